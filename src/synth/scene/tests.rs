//! Tests of the scene generator.

use super::*;
use std::collections::HashMap;

fn params(rho: f64) -> SceneParams {
    SceneParams {
        points_per_m2: rho,
        ..SceneParams::default()
    }
}

fn gen(p: &SceneParams, bounds: &[f64]) -> Vec<SynthPoint> {
    let mut v = Vec::new();
    for w in bounds.windows(2) {
        generate_slab(p, w[0], w[1], &mut v);
    }
    v
}

fn sorted(mut v: Vec<SynthPoint>) -> Vec<SynthPoint> {
    v.sort_by(|a, b| {
        (a.x.total_cmp(&b.x))
            .then(a.y.total_cmp(&b.y))
            .then(a.z.total_cmp(&b.z))
            .then(a.segment.cmp(&b.segment))
    });
    v
}

#[test]
fn slabs_do_not_change_the_scene() {
    let p = params(60.0);
    let one = gen(&p, &[0.0, 100.0]);
    assert!(one.len() > 100_000, "{}", one.len());
    assert!(one.iter().all(|q| q.x >= 0.0 && q.x < 100.0));
    let whole = sorted(one);
    assert_eq!(whole, sorted(gen(&p, &[0.0, 50.0, 100.0])));
    assert_eq!(whole, sorted(gen(&p, &[0.0, 13.0, 14.0, 61.0, 100.0])));
    assert_eq!(whole, sorted(gen(&p, &[-5.0, 33.3, 50.05, 250.0])));
    // Within a slab the order is deterministic too; a different seed changes the scene.
    assert_eq!(gen(&p, &[20.0, 40.0]), gen(&p, &[20.0, 40.0]));
    let q = SceneParams { seed: 7, ..p };
    assert_ne!(whole, sorted(gen(&q, &[0.0, 100.0])));
}

#[test]
fn points_match_segment_truth() {
    let p = params(100.0);
    let segs = segments(&p);
    let mut by_id = HashMap::new();
    for s in &segs {
        assert!(s.id > 0);
        assert!(by_id.insert(s.id, s).is_none(), "duplicate id {}", s.id);
        if s.planar {
            let n = s.normal;
            assert!((n[0] * n[0] + n[1] * n[1] + n[2] * n[2] - 1.0).abs() < 1e-12);
        }
    }
    let pts = gen(&p, &[0.0, 100.0]);
    let tol = 3.0 * p.noise_m + 0.01;
    let mut checked: HashMap<&str, usize> = HashMap::new();
    let mut seen = std::collections::HashSet::new();
    for q in &pts {
        let Some(s) = by_id.get(&q.segment) else {
            panic!("segment {} missing", q.segment)
        };
        assert_eq!(s.class, q.class, "{}", s.kind);
        assert!(
            q.x >= s.x_min - 0.2 && q.x <= s.x_max + 0.2,
            "{} {:?}",
            s.kind,
            q
        );
        seen.insert(s.kind);
        if s.planar {
            let n = s.normal;
            let dist = n[0] * q.x + n[1] * q.y + n[2] * q.z + s.d;
            assert!(dist.abs() < tol, "{} off its plane by {dist}", s.kind);
            *checked.entry(s.kind).or_default() += 1;
        }
    }
    for k in [
        "facade",
        "window",
        "door",
        "road_left",
        "road_right",
        "kerb_face_left",
    ] {
        assert!(
            checked.get(k).copied().unwrap_or(0) > 100,
            "{k}: {checked:?}"
        );
    }
    for (k, class) in KINDS {
        assert!(seen.contains(k), "no points of kind {k}");
        assert!(pts.iter().any(|q| q.class == class));
    }
}

#[test]
fn density_falls_with_distance() {
    let p = params(200.0);
    let pts = gen(&p, &[0.0, 100.0]);
    let segs = segments(&p);
    // Road near the drive line: |y| < 0.5 (cars never reach it).
    let road = pts.iter().filter(|q| q.y.abs() < 0.5).count() as f64 / 100.0;
    // Left facades (incl. windows/doors) between 2 and 4 m height.
    let facade_len: f64 = (segs.iter())
        .filter(|s| s.kind == "facade" && s.normal[1] < 0.0)
        .map(|s| s.x_max - s.x_min)
        .sum();
    let on_facade = |q: &&SynthPoint| q.y > 9.9 && q.y < 10.3 && q.z > 2.0 && q.z < 4.0;
    let facade = pts.iter().filter(on_facade).count() as f64 / (2.0 * facade_len);
    // Expected: 4 × rho near the sensor, (5 / 10.0)^2 rho on the facade (glass is thinner).
    assert!(
        (road / (4.0 * p.points_per_m2) - 1.0).abs() < 0.05,
        "road {road}"
    );
    let expect = 25.0 / (100.0 + 0.5f64.powi(2)) * p.points_per_m2;
    assert!(
        facade > 0.7 * expect && facade < 1.05 * expect,
        "{facade} vs {expect}"
    );
    assert!(road > 10.0 * facade);
}

#[test]
fn default_density_gives_documented_count() {
    let p = SceneParams::default();
    let t = std::time::Instant::now();
    let n = gen(&p, &[0.0, 100.0]).len();
    let s = t.elapsed().as_secs_f64();
    println!("{n} points per 100 m, {:.2} M points/s", n as f64 / s / 1e6);
    assert!((2_100_000..2_700_000).contains(&n), "{n}");
}

#[test]
fn speed() {
    // Best of three 200 m slabs (the machine may be shared).
    let len = if cfg!(debug_assertions) { 20.0 } else { 200.0 };
    let p = SceneParams {
        length_m: len,
        ..SceneParams::default()
    };
    let mut best = 0.0f64;
    let mut v = Vec::new();
    for _ in 0..3 {
        v.clear();
        let t = std::time::Instant::now();
        generate_slab(&p, 0.0, len, &mut v);
        best = best.max(v.len() as f64 / t.elapsed().as_secs_f64());
    }
    println!(
        "generate_slab: {} points, {:.2} M points/s",
        v.len(),
        best / 1e6
    );
    if !cfg!(debug_assertions) {
        assert!(best > 3e6, "{best}");
    }
}

#[test]
fn colours_are_8_bit_times_257_and_bad_input_yields_nothing() {
    let p = params(50.0);
    let pts = gen(&p, &[0.0, 30.0]);
    assert!(pts.iter().all(|q| q.rgb.iter().all(|c| c % 257 == 0)));
    let mut v = Vec::new();
    generate_slab(&p, 50.0, 40.0, &mut v);
    generate_slab(&p, f64::NAN, 40.0, &mut v);
    generate_slab(&p, 100.0, 200.0, &mut v);
    let bad = SceneParams {
        points_per_m2: f64::NAN,
        ..p
    };
    generate_slab(&bad, 0.0, 10.0, &mut v);
    assert!(v.is_empty());
}

#[test]
fn density_does_not_drift_along_a_long_drive() {
    // The road climbs with the grade; the sensor must climb with it, or the scan density
    // falls along the drive.
    let p = SceneParams {
        length_m: 5000.0,
        ..SceneParams::default()
    };
    let count = |x0: f64| {
        let mut v = Vec::new();
        generate_slab(&p, x0, x0 + 20.0, &mut v);
        v.len() as f64
    };
    let (near, far) = (count(100.0), count(4500.0));
    assert!((far / near - 1.0).abs() < 0.2, "near {near}, far {far}");
}
