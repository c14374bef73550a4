//! `tessera info`: facts about a LAS/LAZ file (header) or an MCAP recording.

use std::path::Path;

/// Prints the facts about `file`.
pub fn info(file: &Path) -> anyhow::Result<()> {
    if tessera::io::mcap::is_mcap(file) {
        print!("{}", tessera::io::mcap::info(file)?.to_text());
        return Ok(());
    }
    let f = tessera::io::input::scan_file(file, 0)?;
    let h = &f.header;
    let b = h.bounds();
    println!("file: {}", file.display());
    println!("version: {}", h.version());
    println!(
        "point format: {} (record {} bytes, extra bytes {})",
        h.point_format().to_u8().unwrap_or(255),
        h.point_format().len(),
        h.point_format().extra_bytes
    );
    println!("compressed: {}", h.point_format().is_compressed);
    println!("points: {}", h.number_of_points());
    println!(
        "bounds: x {} .. {}, y {} .. {}, z {} .. {}",
        b.min.x, b.max.x, b.min.y, b.max.y, b.min.z, b.max.z
    );
    let t = h.transforms();
    println!(
        "scale: {} {} {}; offset: {} {} {}",
        t.x.scale, t.y.scale, t.z.scale, t.x.offset, t.y.offset, t.z.offset
    );
    // What the first points look like from above (never fails the command: a file whose points
    // cannot be sampled still has its header shown).
    use tessera::io::detect::{detect, Sample, SAMPLE_POINTS};
    match Sample::of_file(&f, SAMPLE_POINTS).map(|s| detect(&s)) {
        Ok(Some(d)) => println!(
            "looks: {} ({}; {} points sampled, {:.0} % multiple returns, scan angles within {:.0}°)",
            match d.platform {
                tessera::io::detect::Platform::Airborne => "airborne",
                tessera::io::detect::Platform::Mobile => "mobile or terrestrial",
            },
            d.reason,
            d.sampled_points,
            100.0 * d.multiple_returns,
            d.scan_angle_p95_deg
        ),
        Ok(None) => println!("looks: too few points to tell"),
        Err(e) => println!("looks: cannot sample the points ({e})"),
    }
    for v in h.all_vlrs() {
        println!(
            "vlr: {} {} \"{}\" ({} bytes)",
            v.user_id,
            v.record_id,
            v.description,
            v.data.len()
        );
    }
    Ok(())
}
