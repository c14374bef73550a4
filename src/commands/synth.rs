//! `tessera synth`: synthetic street scenes, rows of houses, or simulated drive recordings.

use tessera::cli::{SceneKind, SynthArgs};

/// Writes the scene the arguments name.
pub fn synth(a: SynthArgs) -> anyhow::Result<()> {
    if a.mcap {
        let p = tessera::synth::lidar::LidarParams {
            scene: tessera::synth::SceneParams {
                seed: a.seed,
                length_m: a.length_m,
                ..Default::default()
            },
            rings: a.rings,
            columns: a.columns,
            ..Default::default()
        };
        if let Some(k) = a.scans_every {
            let s = tessera::synth::write_scans(&p, &a.out, k)?;
            tracing::info!(
                "wrote {} single scans ({} points) to {}",
                s.files,
                s.points,
                a.out.display()
            );
            return Ok(());
        }
        let s = tessera::synth::drive::write_drive(&p, &a.out)?;
        tracing::info!(
            "wrote {} clouds ({} returns of {} beams) to {}",
            s.clouds,
            s.points,
            s.beams,
            a.out.join("drive.mcap").display()
        );
        return Ok(());
    }
    if a.scans_every.is_some() {
        return Err(tessera::Error::Config("synth: --scans-every needs --mcap".into()).into());
    }
    if a.scene == SceneKind::Buildings {
        let mut p = tessera::synth::buildings::BuildingParams {
            seed: a.seed,
            houses: a.houses,
            ..Default::default()
        };
        if let Some(d) = a.points_per_m2 {
            p.points_per_m2 = d;
        }
        let s = tessera::synth::write_buildings(&p, &a.out)?;
        tracing::info!(
            "wrote {} points ({} houses) to {}",
            s.points,
            a.houses,
            a.out.display()
        );
        return Ok(());
    }
    let mut p = tessera::synth::SceneParams {
        seed: a.seed,
        length_m: a.length_m,
        ..Default::default()
    };
    if let Some(d) = a.points_per_m2 {
        p.points_per_m2 = d;
    }
    let s = tessera::synth::write_scene(&p, &a.out, a.file_length_m)?;
    tracing::info!(
        "wrote {} points in {} files to {}",
        s.points,
        s.files,
        a.out.display()
    );
    Ok(())
}
