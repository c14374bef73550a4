//! Ray casting of one beam against the analytic street: the nearest of road and side
//! surfaces (with the grass undulation), kerb faces, facades with recessed windows and doors,
//! tree trunks and crowns, poles with arms, and cars as boxes — with the classes, segment ids
//! and colours the scene's point sampler gives the same surfaces.

use super::LidarParams;
use crate::synth::scene::layout::*;
use crate::synth::scene::sample::{tile, ASPHALT, CONCRETE};
use crate::synth::scene::truth;
use nalgebra::{Point3, Vector3};

/// What a beam hit, before noise.
#[derive(Debug, Clone, Copy)]
pub(super) struct Hit {
    pub(super) t: f64,
    pub(super) class: u8,
    pub(super) segment: u32,
    pub(super) col: [f64; 3],
    pub(super) intensity: f64,
}

/// Objects within reach of one revolution.
pub(super) struct Near {
    left: Vec<Building>,
    right: Vec<Building>,
    trees: Vec<Tree>,
    poles: Vec<Pole>,
    cars: Vec<Car>,
    seed: u64,
    length: f64,
}

impl Near {
    pub(super) fn gather(p: &LidarParams, x0: f64, x1: f64) -> Near {
        let seed = p.scene.seed;
        let (lo, hi) = (x0 - p.max_range_m - 30.0, x1 + p.max_range_m + 30.0);
        let lat = |pitch: f64| (lo / pitch).floor() as i64..=(hi / pitch).floor() as i64;
        let mut left = Vec::new();
        let mut right = Vec::new();
        let blocks = &p.scene.blocks;
        for b in lat(blocks.block_m) {
            block_buildings(seed, true, b, blocks, &mut left);
            block_buildings(seed, false, b, blocks, &mut right);
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
pub(super) struct Draws {
    pub(super) bits: u64,
    pub(super) u: f64,
    pub(super) n: [f64; 6],
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
pub(super) fn cast(
    o: &Point3<f64>,
    d: &Vector3<f64>,
    dr: &Draws,
    near: &Near,
    max: f64,
) -> Option<Hit> {
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
