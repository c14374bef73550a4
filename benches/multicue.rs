//! Multi-cue segmentation of organised scans (issue 22) against region growing, scan by scan,
//! on one core: every `sensor_msgs/PointCloud2` of the MCAP files given (default: a simulated
//! drive generated here, and the Ouster recording of `$TESSERA_DATA`) is made into its range
//! image and segmented by the multi-cue method and by region growing on the same points, each
//! timed on a one-thread rayon pool.
//!
//! Prints per input: scans, points, the median points/s per core of both methods, and, where
//! the cloud carries `gt_segment` (the simulated drive), the thesis counts at tolerance 0.8
//! summed over the scans for the integrated result, each cue alone and region growing.
//!
//! Reference segments with fewer than `min_points` points in a scan are left out of that scan's
//! scoring (their points count as unlabelled): no method can find them there.
//!
//! Then the SemanticKITTI frames of `$TESSERA_DATA/semantickitti-open3dml` in the sensor frame
//! (`kitti_01_*`; frame 700 was moved out of the sensor frame and cannot be projected):
//! spherical projection (2048 columns, 64 rows of equal elevation span), and the purity of the
//! segments against the semantic labels (share of segmented points carrying their segment's
//! majority label), for multicue and region growing.
//!
//! Each input's line ends with a checksum of every scan's integrated pixel labels: a change
//! meant to leave the result alone (a faster loop) must leave it unchanged.
//!
//! Usage: `cargo bench --bench multicue [-- FILE.mcap ...]`; env `DRIVE_LENGTH_M` (default 60),
//! `MULTICUE` (TOML overriding `MulticueParams`, e.g. `MULTICUE='hs_px = 1'`), `MULTICUE_ONLY`
//! (set: skip region growing and the scoring, for profiling the multi-cue method alone).

use std::path::{Path, PathBuf};
use std::time::Instant;

use tessera::eval::segments::{evaluate, ToleranceRow};
use tessera::io::mcap::fields::unpack_rgb;
use tessera::io::mcap::pointcloud2::{self, PointCloud2};
use tessera::io::mcap::reader::McapSource;
use tessera::io::mcap::wire::Encoding;
use tessera::segment::features::{rgb_to_lab, LabFormula};
use tessera::segment::multicue::{
    segment_scan, without_small_segments, MulticueParams, Order, RangeImage, Rings,
};
use tessera::segment::{segment_at, SegParams};

/// Sums of the thesis counts over scans.
#[derive(Default, Clone)]
struct Counts {
    reference: usize,
    result: usize,
    correct: usize,
    over: usize,
    under: usize,
    missed: usize,
    noise: usize,
}

impl Counts {
    fn add(&mut self, truth: &[u32], labels: &[u32]) {
        let e = evaluate(truth, labels, None, &[0.8]);
        let r: &ToleranceRow = &e.rows[0];
        self.reference += e.reference_segments;
        self.result += e.result_segments;
        self.correct += r.correct;
        self.over += r.over;
        self.under += r.under;
        self.missed += r.missed;
        self.noise += r.noise;
    }
    fn line(&self, name: &str) -> String {
        format!(
            "    {name:<14} reference {:>6} result {:>6} correct {:>6} ({:>5.1} %) over {:>5} under {:>5} missed {:>6} noise {:>6}",
            self.reference,
            self.result,
            self.correct,
            100.0 * self.correct as f64 / self.reference.max(1) as f64,
            self.over,
            self.under,
            self.missed,
            self.noise
        )
    }
}

struct Scan {
    rows: usize,
    cols: usize,
    xyz: Vec<[f32; 3]>,
    rgb: Option<Vec<[u16; 3]>>,
    truth: Option<Vec<u32>>,
    order: Order,
}

fn scans(path: &Path) -> Vec<Scan> {
    let src = McapSource::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut out = Vec::new();
    src.scan(
        &mut |c| c.message_type() == "sensor_msgs/PointCloud2",
        &mut |m| {
            let enc = Encoding::from_channel(&m.channel.message_encoding).expect("encoding");
            let c: PointCloud2 = pointcloud2::decode(m.data, enc).expect("cloud");
            let get = |name: &str| c.field(name).map(|f| c.accessor(f));
            let (x, y, z) = (get("x").unwrap(), get("y").unwrap(), get("z").unwrap());
            let rgb_acc = get("rgb");
            let gt = get("gt_segment");
            let ring_acc = get("ring");
            let n = c.len();
            let mut s = Scan {
                rows: c.height as usize,
                cols: c.width as usize,
                xyz: Vec::with_capacity(n),
                rgb: rgb_acc.as_ref().map(|_| Vec::with_capacity(n)),
                truth: gt.as_ref().map(|_| Vec::with_capacity(n)),
                order: Order::RowMajor,
            };
            let mut ring = Vec::new();
            for i in 0..n {
                let p = c.point(i);
                s.xyz
                    .push([x.get(p) as f32, y.get(p) as f32, z.get(p) as f32]);
                if let (Some(a), Some(v)) = (&rgb_acc, s.rgb.as_mut()) {
                    v.push(unpack_rgb(a.bits32(p)));
                }
                if let (Some(a), Some(v)) = (&gt, s.truth.as_mut()) {
                    v.push(a.get(p) as u32);
                }
                if let Some(a) = &ring_acc {
                    ring.push(a.get(p) as u32);
                }
            }
            // The ring field tells how the cloud is really laid out (early Ouster drivers
            // wrote column by column).
            if let Some(o) = Order::from_rings(&ring, s.rows, s.cols) {
                s.order = o;
            }
            out.push(s);
            Ok(())
        },
        true,
    )
    .expect("scan");
    out
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

fn run(path: &Path, pool: &rayon::ThreadPool) {
    let scans = scans(path);
    let p: MulticueParams = match std::env::var("MULTICUE") {
        Ok(t) => toml::from_str(&t).expect("MULTICUE: MulticueParams as TOML"),
        Err(_) => MulticueParams::default(),
    };
    p.validate().expect("MULTICUE");
    let sp = SegParams::default();
    let (mut mc_rate, mut rg_rate) = (Vec::new(), Vec::new());
    let mut points = 0usize;
    let mut cue_names: Vec<String> = Vec::new();
    let (mut integrated, mut region, mut cues) = (Counts::default(), Counts::default(), Vec::new());
    let mut secs = [0.0f64; 3];
    let (mut accepted, mut rejected) = (Vec::new(), 0u32);
    let mut checksum = 0xcbf2_9ce4_8422_2325u64;
    for s in &scans {
        let lab: Option<Vec<[f32; 3]>> = s.rgb.as_ref().map(|c| {
            let max = c.iter().flatten().copied().max().unwrap_or(0);
            let scale = if max <= 255 { 255.0 } else { 65535.0 };
            c.iter()
                .map(|v| {
                    rgb_to_lab(v.map(|x| x as f64 / scale), LabFormula::Srgb).map(|x| x as f32)
                })
                .collect()
        });
        let img = match RangeImage::organised(s.rows, s.cols, &s.xyz, lab.as_deref(), s.order) {
            Ok(i) => i,
            Err(e) => {
                eprintln!("  scan skipped: {e}");
                continue;
            }
        };
        let valid = img.valid_count();
        points += valid;
        let t = Instant::now();
        let seg = pool.install(|| segment_scan(&img, &p));
        mc_rate.push(valid as f64 / t.elapsed().as_secs_f64());
        for (a, b) in secs.iter_mut().zip(seg.seconds) {
            *a += b;
        }
        // FNV-1a over every scan's pixel labels: optimisations that must not change the
        // result show it here.
        for &l in &seg.pixel_labels {
            checksum = (checksum ^ l as u64).wrapping_mul(0x100_0000_01b3);
        }
        accepted.resize(seg.integrated.from_cue.len(), 0u32);
        for (a, f) in accepted.iter_mut().zip(&seg.integrated.from_cue) {
            *a += f;
        }
        rejected += seg.integrated.rejected;
        // Region growing on the valid points of the same scan.
        // The points in the image (pixel order and point order differ for column-major
        // clouds).
        let in_image = img.to_points(&vec![1; img.len()], s.xyz.len());
        let idx: Vec<usize> = (0..s.xyz.len()).filter(|&i| in_image[i] == 1).collect();
        let pts: Vec<[f64; 3]> = idx.iter().map(|&i| s.xyz[i].map(|v| v as f64)).collect();
        let rgb: Option<Vec<[u16; 3]>> =
            s.rgb.as_ref().map(|c| idx.iter().map(|&i| c[i]).collect());
        if std::env::var_os("MULTICUE_ONLY").is_some() {
            continue;
        }
        let t = Instant::now();
        let rg = pool
            .install(|| segment_at(&pts, rgb.as_deref(), None, &sp, Some([0.0; 3])))
            .expect("region growing");
        rg_rate.push(valid as f64 / t.elapsed().as_secs_f64());
        if let Some(truth) = &s.truth {
            let mut t: Vec<u32> = idx.iter().map(|&i| truth[i]).collect();
            without_small_segments(&mut t, p.min_points);
            let labels = seg.point_labels(&img, s.xyz.len());
            let pick = |l: &[u32]| -> Vec<u32> { idx.iter().map(|&i| l[i]).collect() };
            integrated.add(&t, &pick(&labels));
            region.add(&t, &rg.labels);
            if cues.is_empty() {
                cues = vec![Counts::default(); seg.cue_labels.len()];
                cue_names = seg
                    .cue_labels
                    .iter()
                    .map(|c| format!("{:?}", c.0))
                    .collect();
            }
            let single = seg.cue_point_labels(&img, s.xyz.len(), p.min_points);
            for (c, labels) in cues.iter_mut().zip(&single) {
                c.add(&t, &pick(labels));
            }
        }
    }
    println!(
        "{}: {} scans, {} valid points; per scan on one core, median: multicue {:.2} M points/s, region growing {:.3} M points/s (ratio {:.1}); multicue seconds: cues {:.2}, mean shift {:.2}, integration {:.2}",
        path.display(),
        scans.len(),
        points,
        median(mc_rate.clone()) / 1e6,
        median(rg_rate.clone()) / 1e6,
        median(mc_rate) / median(rg_rate), // NaN without region growing (`MULTICUE_ONLY`)
        secs[0],
        secs[1],
        secs[2]
    );
    println!(
        "  integration: accepted per cue {accepted:?}, rejected {rejected}; labels checksum {checksum:016x}"
    );
    if integrated.reference > 0 {
        println!("  thesis counts at tolerance 0.8, summed over scans:");
        println!("{}", integrated.line("integrated"));
        for (k, c) in cues.iter().enumerate() {
            println!("{}", c.line(&cue_names[k]));
        }
        println!("{}", region.line("region growing"));
    }
}

/// Reads a little-endian NumPy array of `f4` or `i4` values (C order) as f32 / i32 words.
fn npy(path: &Path) -> (Vec<u32>, Vec<usize>) {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&b[..6], b"\x93NUMPY", "{}", path.display());
    let (hlen, start) = if b[6] == 1 {
        (u16::from_le_bytes([b[8], b[9]]) as usize, 10)
    } else {
        (u32::from_le_bytes([b[8], b[9], b[10], b[11]]) as usize, 12)
    };
    let header = std::str::from_utf8(&b[start..start + hlen]).expect("header");
    assert!(header.contains("<f4") || header.contains("<i4"), "{header}");
    assert!(header.contains("'fortran_order': False"), "{header}");
    let shape: Vec<usize> = header
        .split("'shape': (")
        .nth(1)
        .and_then(|r| r.split(')').next())
        .expect("shape")
        .split(',')
        .filter_map(|v| v.trim().parse().ok())
        .collect();
    let words = b[start + hlen..]
        .chunks_exact(4)
        .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
        .collect();
    (words, shape)
}

/// Share of segmented points whose label is their segment's majority label, and the share of
/// points segmented (`truth` 0 = unlabelled points are left out of both).
fn purity(truth: &[u32], seg: &[u32]) -> (f64, f64) {
    let mut h: std::collections::HashMap<u32, std::collections::HashMap<u32, usize>> =
        Default::default();
    let mut labelled = 0usize;
    for (&t, &s) in truth.iter().zip(seg) {
        if t == 0 {
            continue;
        }
        labelled += 1;
        if s != 0 {
            *h.entry(s).or_default().entry(t).or_insert(0) += 1;
        }
    }
    let (mut major, mut total) = (0usize, 0usize);
    for m in h.values() {
        major += m.values().max().copied().unwrap_or(0);
        total += m.values().sum::<usize>();
    }
    (
        major as f64 / total.max(1) as f64,
        total as f64 / labelled.max(1) as f64,
    )
}

fn kitti(dir: &Path, pool: &rayon::ThreadPool) {
    let p = MulticueParams::default();
    let sp = SegParams::default();
    for f in 0..3 {
        let pts = dir.join(format!("kitti_01_points_{f:06}.npy"));
        let lab = dir.join(format!("kitti_01_labels_{f:06}.npy"));
        if !pts.exists() {
            continue;
        }
        let (w, shape) = npy(&pts);
        assert_eq!(shape.get(1), Some(&3));
        let xyz: Vec<[f32; 3]> = w
            .chunks_exact(3)
            .map(|c| {
                [
                    f32::from_bits(c[0]),
                    f32::from_bits(c[1]),
                    f32::from_bits(c[2]),
                ]
            })
            .collect();
        let truth: Vec<u32> = npy(&lab).0;
        // Ring clusters, reported; the HDL-64E's smear into a few, so the image uses 64
        // uniform rows.
        let gaps = Rings::Gaps {
            gap_deg: 0.2,
            max_rows: 256,
        };
        let found = RangeImage::spherical(&xyz, None, 2048, gaps).map(|(i, _)| i.rows);
        let t = Instant::now();
        let (img, collisions) =
            RangeImage::spherical(&xyz, None, 2048, Rings::Uniform(64)).expect("projection");
        let seg = pool.install(|| segment_scan(&img, &p));
        let mc_s = t.elapsed().as_secs_f64();
        let labels = seg.point_labels(&img, xyz.len());
        let pts64: Vec<[f64; 3]> = xyz.iter().map(|p| p.map(|v| v as f64)).collect();
        if std::env::var_os("MULTICUE_ONLY").is_some() {
            continue;
        }
        let t = Instant::now();
        let rg = pool
            .install(|| segment_at(&pts64, None, None, &sp, Some([0.0; 3])))
            .expect("region growing");
        let rg_s = t.elapsed().as_secs_f64();
        let (mp, mc) = purity(&truth, &labels);
        let (rp, rc) = purity(&truth, &rg.labels);
        println!(
            "kitti_01 frame {f}: {} points, ring clusters by 0.2° gaps: {found:?}, image 64 uniform rows, {} pixel collisions; multicue {} segments, purity {:.1} % of {:.1} % segmented, {:.2} M points/s; region growing {} segments, purity {:.1} % of {:.1} % segmented, {:.3} M points/s",
            xyz.len(),
            collisions,
            seg.segments,
            100.0 * mp,
            100.0 * mc,
            xyz.len() as f64 / mc_s / 1e6,
            rg.segments.len(),
            100.0 * rp,
            100.0 * rc,
            xyz.len() as f64 / rg_s / 1e6
        );
    }
}

fn main() {
    let args: Vec<PathBuf> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .map(PathBuf::from)
        .collect();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let mut inputs = args;
    let _keep;
    if inputs.is_empty() {
        let dir = tempfile::tempdir().expect("tempdir");
        let len: f64 = std::env::var("DRIVE_LENGTH_M")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(60.0);
        let lp = tessera::synth::lidar::LidarParams {
            scene: tessera::synth::SceneParams {
                seed: 7,
                length_m: len,
                ..Default::default()
            },
            ..Default::default()
        };
        tessera::synth::drive::write_drive(&lp, dir.path()).expect("drive");
        inputs.push(dir.path().join("drive.mcap"));
        let data = std::env::var("TESSERA_DATA").unwrap_or_else(|_| "../shared/data".into());
        let ouster = Path::new(&data).join("mcap-ouster-ros1/ouster_os1_ros1profile.mcap");
        if ouster.exists() {
            inputs.push(ouster);
        }
        _keep = dir;
    }
    for p in &inputs {
        run(p, &pool);
    }
    let data = std::env::var("TESSERA_DATA").unwrap_or_else(|_| "../shared/data".into());
    let k = Path::new(&data).join("semantickitti-open3dml");
    if k.is_dir() {
        kitti(&k, &pool);
    }
}
