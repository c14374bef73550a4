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

mod cast;

use super::scene::layout::*;
use super::SceneParams;
use cast::{cast, Draws, Near};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// RNG stream of the simulated sensor.
const R_LIDAR: u64 = 110;
/// Mean-speed modulation of the trajectory: x(t) = v t + A sin(ω t).
const SPEED_A_M: f64 = 2.0;
const SPEED_OMEGA: f64 = 0.6;
/// Lateral weave: y(x) = Y0 + W sin(2π x / L).
const LANE_Y0: f64 = 1.2;
const WEAVE_M: f64 = 0.25;
const WEAVE_L_M: f64 = 50.0;

/// Sensor and drive parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct LidarParams {
    /// The scene (seed, length; `noise_m` is the range noise σ, `colour_noise` the colour
    /// noise σ).
    pub scene: SceneParams,
    /// Beams per firing (e.g. 32 or 64).
    pub rings: u32,
    /// Firings per revolution.
    pub columns: u32,
    /// Revolutions per second.
    pub rate_hz: f64,
    /// Elevation of the lowest and highest beam, degrees.
    pub fov_deg: (f64, f64),
    /// Largest range, metres.
    pub max_range_m: f64,
    /// Mean vehicle speed, m/s.
    pub speed_mps: f64,
}

impl Default for LidarParams {
    /// 32 rings × 1024 columns at 10 Hz, −25°..+15°, 80 m, 8 m/s, scene defaults.
    fn default() -> Self {
        LidarParams {
            scene: SceneParams::default(),
            rings: 32,
            columns: 1024,
            rate_hz: 10.0,
            fov_deg: (-25.0, 15.0),
            max_range_m: 80.0,
            speed_mps: 8.0,
        }
    }
}

impl LidarParams {
    /// Checks the parameters; the message says which is wrong.
    pub fn validate(&self) -> Result<(), String> {
        let s = &self.scene;
        if !(s.length_m.is_finite() && s.length_m > 0.0) {
            return Err(format!("length must be positive, got {}", s.length_m));
        }
        if !(1..=256).contains(&self.rings) || !(16..=8192).contains(&self.columns) {
            return Err(format!(
                "rings must be 1..=256 and columns 16..=8192, got {} and {}",
                self.rings, self.columns
            ));
        }
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0 && self.rate_hz <= 100.0) {
            return Err(format!("rate must be in (0, 100] Hz, got {}", self.rate_hz));
        }
        if !(self.speed_mps.is_finite() && self.speed_mps > 2.0 * SPEED_A_M * SPEED_OMEGA) {
            return Err(format!(
                "speed must exceed {} m/s, got {}",
                2.0 * SPEED_A_M * SPEED_OMEGA,
                self.speed_mps
            ));
        }
        let (lo, hi) = self.fov_deg;
        if !(lo.is_finite() && hi.is_finite() && lo < hi && lo >= -89.0 && hi <= 89.0) {
            return Err(format!("field of view {lo}..{hi} degrees is invalid"));
        }
        if !(self.max_range_m.is_finite() && self.max_range_m > 1.0) {
            return Err(format!(
                "max range must exceed 1 m, got {}",
                self.max_range_m
            ));
        }
        if !(s.noise_m.is_finite() && s.noise_m >= 0.0 && s.colour_noise.is_finite()) {
            return Err("noise must be finite and >= 0".into());
        }
        Ok(())
    }

    /// Nanoseconds from the start of the drive to the start of revolution `k`.
    pub fn revolution_start_ns(&self, k: u64) -> i128 {
        (k as f64 * 1e9 / self.rate_hz).round() as i128
    }

    /// Nanoseconds from the start of a revolution to firing `c`.
    pub fn firing_offset_ns(&self, c: u32) -> u32 {
        (c as f64 * 1e9 / (self.rate_hz * self.columns as f64)).round() as u32
    }

    /// Along-track position at `t` seconds.
    fn x_at(&self, t: f64) -> f64 {
        self.speed_mps * t + SPEED_A_M * (SPEED_OMEGA * t).sin()
    }

    /// Seconds to reach the end of the scene.
    pub fn duration_s(&self) -> f64 {
        let (mut a, mut b) = (
            0.0,
            self.scene.length_m / (self.speed_mps - SPEED_A_M * SPEED_OMEGA),
        );
        for _ in 0..100 {
            let m = 0.5 * (a + b);
            if self.x_at(m) < self.scene.length_m {
                a = m;
            } else {
                b = m;
            }
        }
        b
    }

    /// Complete revolutions in the drive.
    pub fn revolutions(&self) -> u64 {
        (self.duration_s() * self.rate_hz).floor().max(0.0) as u64
    }

    /// Pose of `base_link` in the scene frame at `t` seconds (exact, analytic).
    pub fn vehicle_pose(&self, t: f64) -> Isometry3<f64> {
        let x = self.x_at(t);
        let k = std::f64::consts::TAU / WEAVE_L_M;
        let y = LANE_Y0 + WEAVE_M * (k * x).sin();
        let z = z_road(x, y);
        let yaw = (WEAVE_M * k * (k * x).cos()).atan();
        // Nose up on the climbing road; the +y side lower on the crowned left half.
        let pitch = -GRADE.atan();
        let roll = -(FALL * y.signum()).atan();
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(roll, pitch, yaw),
        )
    }
}

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
