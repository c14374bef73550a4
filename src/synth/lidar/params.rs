//! The simulated sensor's and drive's parameters.

use crate::synth::scene::layout::{z_road, FALL, GRADE};
use crate::synth::SceneParams;
use nalgebra::{Isometry3, Translation3, UnitQuaternion};

/// Mean-speed modulation of the trajectory: x(t) = v t + A sin(ω t).
pub(super) const SPEED_A_M: f64 = 2.0;
pub(super) const SPEED_OMEGA: f64 = 0.6;
/// Lateral weave: y(x) = Y0 + W sin(2π x / L).
pub(super) const LANE_Y0: f64 = 1.2;
pub(super) const WEAVE_M: f64 = 0.25;
pub(super) const WEAVE_L_M: f64 = 50.0;

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
