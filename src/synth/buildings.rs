//! Synthetic coloured buildings for the segmentation gate (thesis chapters 4–5): a row of gabled
//! houses on a lawn, each with walls, two roof facets, a dormer (flat roof, front and two
//! cheeks), windows with painted frames, a door, colour noise and a cast shadow on one wall.
//!
//! Every planar part is its own reference segment. Windows, frames and doors are coplanar with
//! their wall, so only colour separates them (thesis §4.5); the shadow changes brightness on
//! part of a wall without making it another segment. Points are drawn uniformly on each surface
//! (an oblique airborne / terrestrial mix rather than a scan pattern) with isotropic Gaussian
//! position noise. Deterministic for a given seed.

use super::scene::truth;
use super::{SegmentTruth, SynthPoint};

/// Parameters of a building scene.
#[derive(Clone, Debug, PartialEq)]
pub struct BuildingParams {
    /// Seed of every random choice.
    pub seed: u64,
    /// Number of houses in the row (along x).
    pub houses: usize,
    /// Point density on every surface (points/m²).
    pub points_per_m2: f64,
    /// Standard deviation of the position noise (m).
    pub noise_m: f64,
    /// Half-width of the uniform per-channel colour noise, 8-bit units.
    pub colour_noise: f64,
}

impl Default for BuildingParams {
    /// Seed 1, four houses, 400 points/m², 12 mm noise, colour noise ±6.
    fn default() -> Self {
        BuildingParams {
            seed: 1,
            houses: 4,
            points_per_m2: 400.0,
            noise_m: 0.012,
            colour_noise: 6.0,
        }
    }
}

/// Width of a window frame (m).
const FRAME_M: f64 = 0.12;
/// Gap between houses and lawn margin (m).
const GAP_M: f64 = 5.0;
/// Local position of the lawn's south-west corner. Keeps a row of up to four houses inside one
/// 100 m tile of the synthetic world grid (borders at multiples of 100 m from the world
/// offset), so the segmentation gate measures segmentation, not cross-tile stitching.
const SITE_ORIGIN: [f64; 3] = [10.0, 40.0, 0.0];

/// splitmix64 — small, fast and good enough for scene randomness.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }
    fn normal(&mut self) -> f64 {
        let u = self.uniform().max(1e-300);
        let v = self.uniform();
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn unit(a: [f64; 3]) -> [f64; 3] {
    let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    [a[0] / l, a[1] / l, a[2] / l]
}

/// What a surface sample belongs to: segment id and 8-bit colour.
type Hit = Option<(u32, [f64; 3])>;

struct Gen {
    rng: Rng,
    p: BuildingParams,
    pts: Vec<SynthPoint>,
    truth: Vec<SegmentTruth>,
}

impl Gen {
    /// A new reference segment on the plane through `o` spanned by `u`, `v`.
    fn segment(
        &mut self,
        class: u8,
        kind: &'static str,
        o: [f64; 3],
        u: [f64; 3],
        v: [f64; 3],
    ) -> u32 {
        let n = unit(cross(u, v));
        let id = self.truth.len() as u32 + 1;
        self.truth.push(SegmentTruth {
            id,
            class,
            kind,
            planar: true,
            normal: n,
            d: -(n[0] * o[0] + n[1] * o[1] + n[2] * o[2]),
            x_min: f64::INFINITY,
            x_max: f64::NEG_INFINITY,
        });
        id
    }

    /// Samples the parallelogram `o + s·û + t·v̂`, (s, t) ∈ [0, su] × [0, tv]; `f` says which
    /// segment and colour a sample has (or none: a hole). `u`, `v` must be orthogonal.
    fn patch(
        &mut self,
        o: [f64; 3],
        u: [f64; 3],
        v: [f64; 3],
        su: f64,
        tv: f64,
        f: &dyn Fn(f64, f64) -> Hit,
    ) {
        let (u, v) = (unit(u), unit(v));
        let count = (su * tv * self.p.points_per_m2).round() as usize;
        for _ in 0..count {
            let s = self.rng.uniform() * su;
            let t = self.rng.uniform() * tv;
            let Some((id, col)) = f(s, t) else { continue };
            let noise = self.p.noise_m;
            let xyz: [f64; 3] =
                std::array::from_fn(|c| o[c] + s * u[c] + t * v[c] + noise * self.rng.normal());
            let cn = self.p.colour_noise;
            let rgb: [u16; 3] = std::array::from_fn(|c| {
                let x = col[c] + (self.rng.uniform() * 2.0 - 1.0) * cn;
                x.round().clamp(0.0, 255.0) as u16 * 257
            });
            let seg = &mut self.truth[id as usize - 1];
            seg.x_min = seg.x_min.min(xyz[0]);
            seg.x_max = seg.x_max.max(xyz[0]);
            let lum = (col[0] + col[1] + col[2]) / 3.0;
            self.pts.push(SynthPoint {
                x: xyz[0],
                y: xyz[1],
                z: xyz[2],
                rgb,
                intensity: (lum * 200.0) as u16,
                gps_time: self.pts.len() as f64 * 1e-6,
                class: seg.class,
                segment: id,
            });
        }
    }
}

/// A rectangular opening in a wall, in wall coordinates (s along, t up).
#[derive(Clone, Copy)]
struct Opening {
    s0: f64,
    s1: f64,
    t0: f64,
    t1: f64,
    id: u32,
    /// Frame segment id (0: no frame, e.g. a door).
    frame: u32,
}

impl Opening {
    fn hit(&self, s: f64, t: f64, glass: [f64; 3], frame: [f64; 3]) -> Hit {
        if (self.s0..self.s1).contains(&s) && (self.t0..self.t1).contains(&t) {
            return Some((self.id, glass));
        }
        let w = FRAME_M;
        let in_frame =
            (self.s0 - w..self.s1 + w).contains(&s) && (self.t0 - w..self.t1 + w).contains(&t);
        (self.frame != 0 && in_frame).then_some((self.frame, frame))
    }
}

/// Colour palette of one house (8-bit sRGB).
struct Palette {
    wall: [f64; 3],
    roof: [f64; 3],
    frame: [f64; 3],
    door: [f64; 3],
    dormer: [f64; 3],
    dormer_roof: [f64; 3],
}

const WALLS: [[f64; 3]; 4] = [
    [205.0, 185.0, 150.0],
    [160.0, 82.0, 60.0],
    [225.0, 222.0, 210.0],
    [150.0, 150.0, 140.0],
];
const ROOFS: [[f64; 3]; 3] = [[170.0, 62.0, 45.0], [60.0, 62.0, 70.0], [120.0, 75.0, 50.0]];
const GLASS: [f64; 3] = [60.0, 75.0, 100.0];
const GRASS: [f64; 3] = [70.0, 130.0, 55.0];

/// Generates the scene: points (local metres, x along the row) and the reference segments.
pub fn generate(params: &BuildingParams) -> (Vec<SynthPoint>, Vec<SegmentTruth>) {
    let mut g = Gen {
        rng: Rng(params.seed ^ 0xB01D_1465),
        p: params.clone(),
        pts: Vec::new(),
        truth: Vec::new(),
    };
    // Houses first, so the lawn knows their footprints.
    let mut x = GAP_M;
    let mut footprints = Vec::new();
    for _ in 0..params.houses {
        let (w, d) = house(&mut g, x);
        footprints.push([x, x + w, 0.0, d]);
        x += w + GAP_M;
    }
    let lawn = g.segment(
        truth::GRASS,
        "lawn",
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
    );
    let (len, depth) = (x, 8.0 + 2.0 * 4.0);
    g.patch(
        [0.0, -4.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        len,
        depth,
        &|s, t| {
            let (px, py) = (s, t - 4.0);
            let inside = footprints
                .iter()
                .any(|f| px > f[0] && px < f[1] && py > f[2] && py < f[3]);
            (!inside).then_some((lawn, GRASS))
        },
    );
    let t = SITE_ORIGIN;
    for p in &mut g.pts {
        (p.x, p.y, p.z) = (p.x + t[0], p.y + t[1], p.z + t[2]);
    }
    for s in &mut g.truth {
        let n = s.normal;
        s.d -= n[0] * t[0] + n[1] * t[1] + n[2] * t[2];
        s.x_min += t[0];
        s.x_max += t[0];
    }
    (g.pts, g.truth)
}

/// One gabled house with its south-west corner at (x0, 0, 0); returns (width, depth).
fn house(g: &mut Gen, x0: f64) -> (f64, f64) {
    let r = &mut g.rng;
    let (w, d, h) = (r.range(9.0, 12.0), r.range(7.0, 8.0), r.range(4.5, 6.0));
    let pitch = r.range(32.0, 42.0).to_radians();
    let wall_i = (r.next_u64() % WALLS.len() as u64) as usize;
    let pal = Palette {
        wall: WALLS[wall_i],
        roof: ROOFS[(r.next_u64() % ROOFS.len() as u64) as usize],
        // White frames, or dark ones on the light walls.
        frame: if wall_i == 2 {
            [40.0, 70.0, 50.0]
        } else {
            [235.0, 233.0, 226.0]
        },
        door: [110.0, 62.0, 30.0],
        dormer: [232.0, 230.0, 222.0],
        dormer_roof: [115.0, 118.0, 125.0],
    };
    let shadow_from = r.range(0.55, 0.75) * w;
    let slope = pitch.tan();
    let ridge = h + d / 2.0 * slope;
    let (ex, ey, ez) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]);

    // South wall (y = 0): two windows and a door; a cast shadow darkens its east part
    // (soft edge) without making it another surface.
    let south = g.segment(truth::BUILDING, "wall", [x0, 0.0, 0.0], ex, ez);
    let mut openings = Vec::new();
    for s0 in [0.15 * w, 0.7 * w] {
        let id = g.segment(truth::BUILDING, "window", [x0, 0.0, 0.0], ex, ez);
        let frame = g.segment(truth::BUILDING, "window_frame", [x0, 0.0, 0.0], ex, ez);
        openings.push(Opening {
            s0,
            s1: s0 + 1.2,
            t0: 1.4,
            t1: 2.7,
            id,
            frame,
        });
    }
    let door = g.segment(truth::BUILDING, "door", [x0, 0.0, 0.0], ex, ez);
    let door_s = 0.45 * w;
    let door_o = Opening {
        s0: door_s,
        s1: door_s + 1.0,
        t0: -1.0,
        t1: 2.1,
        id: door,
        frame: 0,
    };
    let (wall_c, frame_c, door_c) = (pal.wall, pal.frame, pal.door);
    g.patch([x0, 0.0, 0.0], ex, ez, w, h, &|s, t| {
        let shade = 1.0 - 0.25 * ((s - shadow_from) / 0.8).clamp(0.0, 1.0);
        let dim = |c: [f64; 3]| c.map(|v| v * shade);
        openings
            .iter()
            .find_map(|o| o.hit(s, t, dim(GLASS), dim(frame_c)))
            .or_else(|| door_o.hit(s, t, dim(door_c), dim(frame_c)))
            .or(Some((south, dim(wall_c))))
    });

    // North wall (y = d): one framed window.
    let north = g.segment(truth::BUILDING, "wall", [x0, d, 0.0], ex, ez);
    let id = g.segment(truth::BUILDING, "window", [x0, d, 0.0], ex, ez);
    let frame = g.segment(truth::BUILDING, "window_frame", [x0, d, 0.0], ex, ez);
    let win = Opening {
        s0: 0.4 * w,
        s1: 0.4 * w + 1.5,
        t0: 1.4,
        t1: 2.7,
        id,
        frame,
    };
    g.patch([x0, d, 0.0], ex, ez, w, h, &|s, t| {
        win.hit(s, t, GLASS, frame_c).or(Some((north, wall_c)))
    });

    // Gable walls (x = x0, x0 + w): rectangle plus triangle.
    for gx in [x0, x0 + w] {
        let id = g.segment(truth::BUILDING, "gable", [gx, 0.0, 0.0], ey, ez);
        g.patch([gx, 0.0, 0.0], ey, ez, d, ridge, &|s, t| {
            let top = h + (d / 2.0 - (s - d / 2.0).abs()) * slope;
            (t <= top).then_some((id, wall_c))
        });
    }

    // Dormer on the south facet: flat roof at zr, front at y = dy0, cheeks at dx0 / dx1.
    let (dx0, dx1) = (x0 + 0.35 * w, x0 + 0.35 * w + 2.2);
    let dy0 = 1.2;
    let zf = h + dy0 * slope;
    let zr = zf + 1.3;
    let dy1 = (zr - h) / slope;
    let on_dormer = move |x: f64, y: f64| (dx0..dx1).contains(&x) && (dy0..dy1).contains(&y);
    let run = d / 2.0;
    let len = (run * run + (run * slope).powi(2)).sqrt();
    let roof_c = pal.roof;
    let sv = [0.0, run, run * slope];
    let south_roof = g.segment(truth::BUILDING, "roof", [x0, 0.0, h], ex, sv);
    g.patch([x0, 0.0, h], ex, sv, w, len, &|s, t| {
        (!on_dormer(x0 + s, t / len * run)).then_some((south_roof, roof_c))
    });
    let nv = [0.0, -run, run * slope];
    let north_roof = g.segment(truth::BUILDING, "roof", [x0, d, h], ex, nv);
    g.patch([x0, d, h], ex, nv, w, len, &|_, _| {
        Some((north_roof, roof_c))
    });
    let top = g.segment(truth::BUILDING, "dormer_roof", [dx0, dy0, zr], ex, ey);
    let top_c = pal.dormer_roof;
    g.patch([dx0, dy0, zr], ex, ey, dx1 - dx0, dy1 - dy0, &|_, _| {
        Some((top, top_c))
    });
    let front = g.segment(truth::BUILDING, "dormer_front", [dx0, dy0, zf], ex, ez);
    let dormer_c = pal.dormer;
    g.patch([dx0, dy0, zf], ex, ez, dx1 - dx0, zr - zf, &|_, _| {
        Some((front, dormer_c))
    });
    for cx in [dx0, dx1] {
        let id = g.segment(truth::BUILDING, "dormer_cheek", [cx, dy0, zf], ey, ez);
        g.patch([cx, dy0, zf], ey, ez, dy1 - dy0, zr - zf, &|s, t| {
            (zf + t >= h + (dy0 + s) * slope).then_some((id, dormer_c))
        });
    }
    (w, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deterministic_and_every_segment_has_points() {
        let p = BuildingParams {
            houses: 2,
            points_per_m2: 50.0,
            ..Default::default()
        };
        let (a, ta) = generate(&p);
        let (b, tb) = generate(&p);
        assert_eq!(a, b);
        assert_eq!(ta, tb);
        let mut count = vec![0usize; ta.len() + 1];
        for q in &a {
            count[q.segment as usize] += 1;
        }
        assert!(count[1..].iter().all(|&c| c > 0), "{count:?}");
        // Per house: 4 walls, 3 windows + 3 frames, 1 door, 2 roofs, 4 dormer faces; one lawn.
        assert_eq!(ta.len(), 2 * 17 + 1);
        // Points lie on their segment's plane (within the noise).
        for q in a.iter().step_by(97) {
            let s = &ta[q.segment as usize - 1];
            let r = s.normal[0] * q.x + s.normal[1] * q.y + s.normal[2] * q.z + s.d;
            assert!(r.abs() < 0.1, "{} {r}", s.kind);
        }
    }
}
