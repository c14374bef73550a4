//! A simulated spinning LiDAR on a vehicle driving through the synthetic street scene.
//!
//! The vehicle follows an analytic trajectory (speed varying around `speed_mps`, a gentle
//! lateral weave in the left lane, pitch and roll from the road's grade and cross-fall); the
//! sensor sits on a fixed, slightly tilted mount. Every revolution fires `columns` azimuth
//! steps of `rings` beams; each beam is ray-cast against the analytic scene — road, kerbs,
//! side surfaces with the grass undulation, facades with recessed windows and doors, tree
//! trunks and crowns, poles with arms, cars as boxes — with the scene's own layout, classes and
//! segment ids (so `segments.tsv` of the scene describes the drive). Ranges get Gaussian noise
//! along the beam; beams that hit nothing within range (or leave the scene) are no-returns.
//!
//! Each return keeps its truth: the world position it was measured at (the exact pose at the
//! firing time, not an interpolated one), class and segment, so a decoded, georeferenced drive
//! can be checked point by point. Revolutions are independent and deterministic (one RNG
//! stream per revolution), so they are simulated in parallel.

mod params;
pub use params::*;

mod cast;

use super::scene::layout::*;
use cast::{cast, Draws, Near};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// RNG stream of the simulated sensor.
const R_LIDAR: u64 = 110;

/// The sensor mount: pose of the lidar frame in `base_link` (1.9 m up, tilted and turned a
/// little so the chain of transforms is not trivial).
pub fn mount() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.3, 0.0, 1.9),
        UnitQuaternion::from_euler_angles(0.01, 0.05, 0.02),
    )
}

/// One return of a beam.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Return {
    /// Position in the lidar frame, as the sensor reports it.
    pub sensor: [f32; 3],
    /// True position in the scene frame (measured range along the true beam).
    pub world: [f64; 3],
    /// Return strength.
    pub intensity: f32,
    /// Colour (as a camera-colourised scanner would give it).
    pub rgb: [u8; 3],
    /// Truth class, see [`crate::synth::scene::truth`].
    pub class: u8,
    /// Truth segment id (as in the scene's `segments.tsv`).
    pub segment: u32,
}

/// One revolution: beams in row-major order (ring rows × firing columns).
#[derive(Debug, Clone)]
pub struct Revolution {
    /// Revolution index.
    pub index: u64,
    /// Start, ns after the start of the drive.
    pub start_ns: i128,
    /// `rings × columns` beams, `None` for no return.
    pub beams: Vec<Option<Return>>,
}

/// Simulates revolution `k`.
pub fn simulate_revolution(p: &LidarParams, k: u64) -> Revolution {
    let start_ns = p.revolution_start_ns(k);
    let t0 = start_ns as f64 * 1e-9;
    let t1 = p.revolution_start_ns(k + 1) as f64 * 1e-9;
    let near = Near::gather(
        p,
        p.vehicle_pose(t0).translation.x,
        p.vehicle_pose(t1).translation.x,
    );
    let mount = mount();
    let (lo, hi) = (p.fov_deg.0.to_radians(), p.fov_deg.1.to_radians());
    let rings = p.rings as usize;
    let cols = p.columns as usize;
    let elev: Vec<(f64, f64)> = (0..rings)
        .map(|r| {
            let e = if rings == 1 {
                0.5 * (lo + hi)
            } else {
                lo + (hi - lo) * r as f64 / (rings - 1) as f64
            };
            e.sin_cos()
        })
        .collect();
    let mut rng = Rng(hash(p.scene.seed, R_LIDAR, k as i64));
    let noise = p.scene.noise_m.abs();
    let cn = p.scene.colour_noise.abs();
    let mut beams = vec![None; rings * cols];
    for c in 0..cols {
        let tf = (start_ns + p.firing_offset_ns(c as u32) as i128) as f64 * 1e-9;
        let pose = p.vehicle_pose(tf) * mount;
        let o = pose * Point3::origin();
        let (sa, ca) = (std::f64::consts::TAU * c as f64 / cols as f64).sin_cos();
        for (r, (se, ce)) in elev.iter().enumerate() {
            let ds = Vector3::new(ce * ca, ce * sa, *se);
            let d = pose.rotation * ds;
            let (n0, n1) = rng.normal_pair();
            let (n2, n3) = rng.normal_pair();
            let (n4, n5) = rng.normal_pair();
            let dr = Draws {
                bits: rng.next(),
                u: rng.u(),
                n: [n0, n1, n2, n3, n4, n5],
            };
            let Some(h) = cast(&o, &d, &dr, &near, p.max_range_m) else {
                continue;
            };
            let range = (h.t + dr.n[0] * noise).max(0.01);
            let w = o + d * range;
            let s = ds * range;
            let ch = |v: f64, n: f64| (v + n * cn).round().clamp(0.0, 255.0) as u8;
            beams[r * cols + c] = Some(Return {
                sensor: [s.x as f32, s.y as f32, s.z as f32],
                world: [w.x, w.y, w.z],
                intensity: (h.intensity * (1.0 + 0.04 * dr.n[1])).clamp(0.0, 65535.0) as f32,
                rgb: [
                    ch(h.col[0], dr.n[2]),
                    ch(h.col[1], dr.n[3]),
                    ch(h.col[2], dr.n[4]),
                ],
                class: h.class,
                segment: h.segment,
            });
        }
    }
    Revolution {
        index: k,
        start_ns,
        beams,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::scene::truth;
    use crate::synth::SceneParams;

    fn small() -> LidarParams {
        LidarParams {
            scene: SceneParams {
                length_m: 60.0,
                ..Default::default()
            },
            rings: 16,
            columns: 256,
            ..Default::default()
        }
    }

    #[test]
    fn trajectory_reaches_the_end_and_drives_in_the_left_lane() {
        let p = small();
        let t = p.duration_s();
        assert!((p.vehicle_pose(t).translation.x - 60.0).abs() < 1e-6);
        for k in 0..100 {
            let v = p.vehicle_pose(t * k as f64 / 100.0).translation.vector;
            assert!(v.y > 0.9 && v.y < 1.5, "{v}");
            assert!((v.z - z_road(v.x, v.y)).abs() < 1e-12);
        }
        assert_eq!(p.revolutions(), (t * 10.0).floor() as u64);
    }

    #[test]
    fn returns_lie_on_the_surfaces_they_claim() {
        let mut p = small();
        p.scene.noise_m = 0.0;
        let rev = simulate_revolution(&p, 30);
        let hits: Vec<&Return> = rev.beams.iter().flatten().collect();
        assert!(hits.len() > rev.beams.len() / 3, "{} hits", hits.len());
        let mut seen = std::collections::BTreeSet::new();
        for h in &hits {
            let [x, y, z] = h.world;
            seen.insert(h.class);
            let kind = h.segment >> 26;
            match kind {
                K_ROAD_L | K_ROAD_R => assert!((z - z_road(x, y)).abs() < 1e-9),
                K_KTOP_L | K_KTOP_R | K_CYCLE | K_FOOT_L | K_FOOT_R => {
                    assert!((z - z_side(x, y)).abs() < 1e-9)
                }
                K_GRASS => assert!((z - z_side(x, y) - grass_bump(x, y)).abs() < 1e-6),
                K_KFACE_L | K_KFACE_R => assert!((y.abs() - ROAD_HALF).abs() < 1e-9),
                K_FACADE => {
                    assert!(
                        (y - FACADE_L).abs() < 1e-9 || (y - FACADE_R).abs() < 1e-9,
                        "{y}"
                    )
                }
                K_WINDOW => assert!(
                    (y - FACADE_L - WIN_RECESS).abs() < 1e-9
                        || (y - FACADE_R + WIN_RECESS).abs() < 1e-9,
                    "{y}"
                ),
                _ => {}
            }
            assert!((0.0..60.0).contains(&x));
        }
        assert!(
            seen.contains(&truth::ROAD) && seen.contains(&truth::BUILDING),
            "{seen:?}"
        );
    }

    #[test]
    fn revolutions_are_deterministic() {
        let p = small();
        let a = simulate_revolution(&p, 5);
        let b = simulate_revolution(&p, 5);
        assert_eq!(a.beams, b.beams);
        let c = simulate_revolution(&p, 6);
        assert_ne!(a.beams, c.beams);
    }
}
