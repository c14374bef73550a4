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

use super::scene::layout::*;
use super::scene::sample::{tile, ASPHALT, CONCRETE};
use super::scene::truth;
use super::SceneParams;
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
    /// Truth class, see [`truth`].
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

/// What a beam hit, before noise.
#[derive(Debug, Clone, Copy)]
struct Hit {
    t: f64,
    class: u8,
    segment: u32,
    col: [f64; 3],
    intensity: f64,
}

/// Objects within reach of one revolution.
struct Near {
    left: Vec<Building>,
    right: Vec<Building>,
    trees: Vec<Tree>,
    poles: Vec<Pole>,
    cars: Vec<Car>,
    seed: u64,
    length: f64,
}

impl Near {
    fn gather(p: &LidarParams, x0: f64, x1: f64) -> Near {
        let seed = p.scene.seed;
        let (lo, hi) = (x0 - p.max_range_m - 30.0, x1 + p.max_range_m + 30.0);
        let lat = |pitch: f64| (lo / pitch).floor() as i64..=(hi / pitch).floor() as i64;
        let mut left = Vec::new();
        let mut right = Vec::new();
        for b in lat(BUILD_BLOCK) {
            block_buildings(seed, true, b, &mut left);
            block_buildings(seed, false, b, &mut right);
        }
        left.sort_by(|a, b| a.xa.total_cmp(&b.xa));
        right.sort_by(|a, b| a.xa.total_cmp(&b.xa));
        Near {
            left,
            right,
            trees: lat(TREE_PITCH).filter_map(|i| tree(seed, i)).collect(),
            poles: lat(POLE_PITCH).filter_map(|i| pole(seed, i)).collect(),
            cars: lat(CAR_PITCH).filter_map(|i| car(seed, i)).collect(),
            seed,
            length: p.scene.length_m,
        }
    }
}

/// Random draws of one beam (always the same number per beam, whatever it hits).
struct Draws {
    bits: u64,
    u: f64,
    n: [f64; 6],
}

fn keep(best: &mut Option<Hit>, h: Hit) {
    if best.is_none_or(|b| h.t < b.t) {
        *best = Some(h);
    }
}

/// Ray parameter where the ray meets the plane z = G x + by y + c.
#[inline]
fn t_height_plane(o: &Point3<f64>, d: &Vector3<f64>, by: f64, c: f64) -> Option<f64> {
    let den = GRADE * d.x + by * d.y - d.z;
    if den.abs() < 1e-12 {
        return None;
    }
    let t = (o.z - GRADE * o.x - by * o.y - c) / den;
    (t > 1e-6).then_some(t)
}

fn ground(o: &Point3<f64>, d: &Vector3<f64>, dr: &Draws, near: &Near, best: &mut Option<Hit>) {
    let c0 = -FALL * ROAD_HALF + KERB_H;
    let bands: [(f64, f64, f64, f64); 6] = [
        (0.0, ROAD_HALF, -FALL, 0.0),
        (-ROAD_HALF, 0.0, FALL, 0.0),
        (ROAD_HALF, KERB_OUT, 0.0, c0),
        (KERB_OUT, FACADE_L, SIDE_FALL, c0 - SIDE_FALL * KERB_OUT),
        (-KERB_OUT, -ROAD_HALF, 0.0, c0),
        (FACADE_R, -KERB_OUT, -SIDE_FALL, c0 - SIDE_FALL * KERB_OUT),
    ];
    for (ya, yb, by, c) in bands {
        let Some(mut t) = t_height_plane(o, d, by, c) else {
            continue;
        };
        let mut h = o + d * t;
        if !(h.y >= ya && h.y < yb) {
            continue;
        }
        if (CYCLE_OUT..GRASS_OUT).contains(&h.y) {
            // Grass undulates (|bump| < 0.045 m) around its plane. Along the ray the height
            // above the plane changes at rate `den`, so the surface is crossed within
            // 0.05 / |den| of the plane hit: bisect there.
            let f = |t: f64| {
                let q = o + d * t;
                q.z - (GRADE * q.x + by * q.y + c + grass_bump(q.x, q.y))
            };
            let den = (GRADE * d.x + by * d.y - d.z).abs().max(1e-9);
            let (mut a, mut b) = ((t - 0.05 / den).max(1e-6), t + 0.05 / den);
            if f(a) * f(b) > 0.0 {
                continue;
            }
            for _ in 0..60 {
                let m = 0.5 * (a + b);
                if f(a) * f(m) <= 0.0 {
                    b = m;
                } else {
                    a = m;
                }
            }
            t = 0.5 * (a + b);
            h = o + d * t;
            if !(CYCLE_OUT..GRASS_OUT).contains(&h.y) {
                continue;
            }
        }
        if best.is_some_and(|b| b.t <= t) {
            continue;
        }
        keep(best, ground_material(h.x, h.y, t, dr, near.seed));
    }
    // Kerb faces.
    for (y, kind) in [(ROAD_HALF, K_KFACE_L), (-ROAD_HALF, K_KFACE_R)] {
        if d.y.abs() < 1e-12 {
            continue;
        }
        let t = (y - o.y) / d.y;
        if t <= 1e-6 {
            continue;
        }
        let h = o + d * t;
        let zr = z_road(h.x, y);
        if h.z >= zr && h.z < zr + KERB_H {
            keep(
                best,
                Hit {
                    t,
                    class: truth::KERB,
                    segment: sid(kind, block_of(h.x, ROAD_BLOCK)),
                    col: CONCRETE,
                    intensity: 22000.0,
                },
            );
        }
    }
}

/// Class, segment and colour of the ground at (x, y) (as the scene's point sampler does).
fn ground_material(x: f64, y: f64, t: f64, dr: &Draws, seed: u64) -> Hit {
    let (ay, blk) = (y.abs(), block_of(x, ROAD_BLOCK));
    let jit = (dr.u - 0.5) * 16.0;
    let white = [225.0, 225.0, 220.0];
    let (kind, idx, col, intensity) = if ay < ROAD_HALF {
        if ay < 0.06 && x.rem_euclid(DASH_PITCH) < DASH_LEN {
            (K_DASH, block_of(x, DASH_PITCH), white, 42000.0)
        } else if (3.15..3.3).contains(&ay) {
            (
                if y > 0.0 { K_EDGE_L } else { K_EDGE_R },
                blk,
                white,
                42000.0,
            )
        } else {
            let k = if y > 0.0 { K_ROAD_L } else { K_ROAD_R };
            (k, blk, ASPHALT.map(|v| v + jit), 9000.0)
        }
    } else if ay < KERB_OUT {
        (
            if y > 0.0 { K_KTOP_L } else { K_KTOP_R },
            blk,
            CONCRETE,
            22000.0,
        )
    } else if y < 0.0 || ay >= GRASS_OUT {
        let (col, int) = tile(seed, x, y);
        (if y > 0.0 { K_FOOT_L } else { K_FOOT_R }, blk, col, int)
    } else if ay < CYCLE_OUT {
        let j = jit * 0.75;
        (K_CYCLE, blk, [150.0 + j, 62.0 + j, 55.0 + j], 12000.0)
    } else {
        let p = 12.0 * (0.7 * x).sin() * (1.3 * y).cos() + 2.0 * jit;
        (K_GRASS, blk, [70.0 + 0.5 * p, 120.0 + p, 45.0], 16000.0)
    };
    Hit {
        t,
        class: class_of(kind),
        segment: sid(kind, idx),
        col,
        intensity,
    }
}

fn facades(
    o: &Point3<f64>,
    d: &Vector3<f64>,
    dr: &Draws,
    near: &Near,
    best: &mut Option<Hit>,
) -> bool {
    let (list, left) = if d.y > 1e-9 {
        (&near.left, true)
    } else if d.y < -1e-9 {
        (&near.right, false)
    } else {
        return false;
    };
    let y0 = if left { FACADE_L } else { FACADE_R };
    let t = (y0 - o.y) / d.y;
    if t <= 1e-6 || best.is_some_and(|b| b.t <= t) {
        return false;
    }
    let h = o + d * t;
    let i = list.partition_point(|b| b.xa <= h.x);
    let Some(b) = i.checked_sub(1).map(|i| &list[i]).filter(|b| h.x < b.xb) else {
        return false;
    };
    let v = h.z - b.z0;
    if v > b.h || h.z < z_side(h.x, b.y) {
        return false;
    }
    let shade = if b.left { 1.0 } else { 0.78 };
    let wall = |t: f64| {
        let j = 0.94 + 0.12 * dr.u;
        Hit {
            t,
            class: truth::BUILDING,
            segment: sid(K_FACADE, b.gid),
            col: b.col.map(|c| c * j * shade),
            intensity: 18000.0,
        }
    };
    let opening = b.opening(h.x, v);
    let recess = match opening {
        Opening::Wall => {
            keep(best, wall(t));
            return false;
        }
        Opening::Window(..) => 1,
        Opening::Door => 2,
    };
    let t2 = (b.plane_y(recess) - o.y) / d.y;
    let h2 = o + d * t2;
    match (opening, b.opening(h2.x, h2.z - b.z0)) {
        (Opening::Window(w, _), Opening::Window(w2, frame)) if w == w2 => {
            if !frame && (dr.bits & 0xFF) < 102 {
                return true; // glass: 40 % of the beams give no echo
            }
            let (col, int) = if frame {
                (b.frame, 25000.0)
            } else {
                ([38.0, 48.0, 60.0], 4000.0)
            };
            keep(
                best,
                Hit {
                    t: t2,
                    class: truth::BUILDING,
                    segment: sid(K_WINDOW, b.gid * 128 + u64::from(w)),
                    col: col.map(|c| c * shade),
                    intensity: int,
                },
            );
        }
        (Opening::Door, Opening::Door) => keep(
            best,
            Hit {
                t: t2,
                class: truth::BUILDING,
                segment: sid(K_DOOR, b.gid),
                col: b.door_col.map(|c| c * shade),
                intensity: 12000.0,
            },
        ),
        // The beam meets the reveal of the opening: counted as wall.
        _ => keep(best, wall(t)),
    }
    false
}

/// Entry and exit of the ray in a vertical cylinder around (cx, cy) of radius r.
fn vertical_cylinder(o: &Point3<f64>, d: &Vector3<f64>, cx: f64, cy: f64, r: f64) -> Option<f64> {
    let (ox, oy) = (o.x - cx, o.y - cy);
    let a = d.x * d.x + d.y * d.y;
    if a < 1e-12 {
        return None;
    }
    let b = ox * d.x + oy * d.y;
    let c = ox * ox + oy * oy - r * r;
    let disc = b * b - a * c;
    if disc < 0.0 {
        return None;
    }
    let t = (-b - disc.sqrt()) / a;
    (t > 1e-6).then_some(t)
}

fn trees(o: &Point3<f64>, d: &Vector3<f64>, dr: &Draws, near: &Near, best: &mut Option<Hit>) {
    for tr in &near.trees {
        if let Some(t) = vertical_cylinder(o, d, tr.x, tr.y, 0.15) {
            let z = o.z + d.z * t;
            if z >= tr.g && z < tr.zc - 0.6 * tr.b {
                keep(
                    best,
                    Hit {
                        t,
                        class: truth::HIGH_VEGETATION,
                        segment: sid(K_TRUNK, tr.i),
                        col: [90.0, 65.0, 45.0],
                        intensity: 10000.0,
                    },
                );
            }
        }
        // Crown: an ellipsoid of leaves; a quarter of the beams pass through gaps, the rest
        // echo from a little inside the shell.
        let q = Vector3::new(
            (o.x - tr.x) / tr.a,
            (o.y - tr.y) / tr.a,
            (o.z - tr.zc) / tr.b,
        );
        let e = Vector3::new(d.x / tr.a, d.y / tr.a, d.z / tr.b);
        let (a, b, c) = (e.dot(&e), q.dot(&e), q.dot(&q) - 1.0);
        let disc = b * b - a * c;
        if disc <= 0.0 || (dr.bits >> 8) & 3 == 0 {
            continue;
        }
        let (t1, t2) = ((-b - disc.sqrt()) / a, (-b + disc.sqrt()) / a);
        if t2 <= 1e-6 {
            continue;
        }
        let t = t1.max(1e-6) + (t2 - t1.max(1e-6)) * 0.3 * dr.u * dr.u;
        let l = 0.7 + 0.55 * (((dr.bits >> 16) & 0xFFFF) as f64 / 65535.0);
        keep(
            best,
            Hit {
                t,
                class: truth::HIGH_VEGETATION,
                segment: sid(K_CROWN, tr.i),
                col: tr.col.map(|v| v * l),
                intensity: 14000.0,
            },
        );
    }
}

fn poles(o: &Point3<f64>, d: &Vector3<f64>, near: &Near, best: &mut Option<Hit>) {
    let col = [120.0, 125.0, 130.0];
    for p in &near.poles {
        let hit = |t: f64| Hit {
            t,
            class: truth::POLE,
            segment: sid(K_POLE, p.i),
            col,
            intensity: 26000.0,
        };
        let top = p.g + p.h;
        if let Some(t) = vertical_cylinder(o, d, p.x, p.y, 0.08) {
            let z = o.z + d.z * t;
            if z >= p.g && z < top {
                keep(best, hit(t));
            }
        }
        // Arm: a horizontal cylinder along y, 1.5 m long, 0.3 m below the top.
        let (za, ra) = (top - 0.3, 0.05);
        let (ox, oz) = (o.x - p.x, o.z - za);
        let a = d.x * d.x + d.z * d.z;
        if a > 1e-12 {
            let b = ox * d.x + oz * d.z;
            let disc = b * b - a * (ox * ox + oz * oz - ra * ra);
            if disc >= 0.0 {
                let t = (-b - disc.sqrt()) / a;
                let y = o.y + d.y * t;
                if t > 1e-6 && y >= p.y && y < p.y + 1.5 {
                    keep(best, hit(t));
                }
            }
        }
    }
}

/// Slab test: entry distance and the axis of the entry face.
fn aabb(o: &Point3<f64>, d: &Vector3<f64>, lo: [f64; 3], hi: [f64; 3]) -> Option<(f64, usize)> {
    let (mut t0, mut t1, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
    for k in 0..3 {
        if d[k].abs() < 1e-12 {
            if o[k] < lo[k] || o[k] > hi[k] {
                return None;
            }
            continue;
        }
        let (mut a, mut b) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
        if a > b {
            std::mem::swap(&mut a, &mut b);
        }
        if a > t0 {
            t0 = a;
            axis = k;
        }
        t1 = t1.min(b);
    }
    (t0 <= t1 && t0 > 1e-6).then_some((t0, axis))
}

fn cars(o: &Point3<f64>, d: &Vector3<f64>, near: &Near, best: &mut Option<Hit>) {
    for v in &near.cars {
        for (lo, hi, cab) in [
            ([v.xa, v.ya, v.zb], [v.xb, v.yb, v.zt], false),
            ([v.cxa, v.cya, v.zt], [v.cxb, v.cyb, v.czt], true),
        ] {
            let Some((t, axis)) = aabb(o, d, lo, hi) else {
                continue;
            };
            let h = o + d * t;
            // Cabin sides and ends are glass except the pillars (as in the point sampler).
            let inner = match axis {
                1 => (h.x - lo[0]).min(hi[0] - h.x) > 0.12,
                0 => (h.y - lo[1]).min(hi[1] - h.y) > 0.1,
                _ => false,
            };
            let glass = cab && inner && h.z > lo[2] + 0.05;
            let (col, intensity) = if glass {
                ([30.0, 35.0, 45.0], 5000.0)
            } else {
                (v.col, 28000.0)
            };
            keep(
                best,
                Hit {
                    t,
                    class: truth::VEHICLE,
                    segment: sid(K_CAR, v.i),
                    col,
                    intensity,
                },
            );
        }
    }
}

/// The nearest hit of a beam from `o` along unit `d` (`None`: no return).
fn cast(o: &Point3<f64>, d: &Vector3<f64>, dr: &Draws, near: &Near, max: f64) -> Option<Hit> {
    let mut best: Option<Hit> = None;
    cars(o, d, near, &mut best);
    poles(o, d, near, &mut best);
    trees(o, d, dr, near, &mut best);
    if facades(o, d, dr, near, &mut best) {
        return None;
    }
    ground(o, d, dr, near, &mut best);
    let h = best?;
    let x = o.x + d.x * h.t;
    (h.t <= max && x >= 0.0 && x < near.length).then_some(h)
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
