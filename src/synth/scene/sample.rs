//! Point emission: scan density, noise, colours and the sampling of every surface of a cell.

use super::layout::*;
use super::{truth, SynthPoint};
use std::f64::consts::TAU;

// ---------------------------------------------------------------------------------------------
// Point emission.

/// Point sink of one slab: density model, noise and the slab filter.
pub struct Em<'a> {
    pub out: &'a mut Vec<SynthPoint>,
    pub rng: Rng,
    pub lo: f64,
    pub hi: f64,
    pub noise: f64,
    pub rho: f64,
    pub h: f64,
    /// 4096 Box–Muller normals times the colour noise (a fixed table: colour noise is drawn
    /// by 12-bit index, three channels from one 64-bit draw).
    pub ctab: Vec<f64>,
}

impl<'a> Em<'a> {
    /// Sink for points with final x in `[lo, hi)`.
    pub fn new(out: &'a mut Vec<SynthPoint>, lo: f64, hi: f64, p: &super::SceneParams) -> Self {
        let mut r = Rng(0x5EED_C010_0125);
        let cn = p.colour_noise.abs();
        let ctab = (0..2048)
            .flat_map(|_| {
                let (a, b) = r.normal_pair();
                [a * cn, b * cn]
            })
            .collect();
        Em {
            out,
            rng: Rng(0),
            lo,
            hi,
            noise: p.noise_m.abs(),
            rho: p.points_per_m2,
            h: p.sensor_height_m,
            ctab,
        }
    }

    /// Scan density at (y, z): `rho (5 m / r)^2`, capped at 4 × rho.
    #[inline]
    pub fn dens(&self, y: f64, z: f64) -> f64 {
        let r2 = y * y + (z - self.h) * (z - self.h);
        self.rho * (25.0 / r2.max(1e-9)).min(4.0)
    }

    /// Adds noise and keeps the point if its final x lies in the slab. All random draws happen
    /// before the test so that the stream never depends on the slab.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub fn push(&mut self, x: f64, y: f64, z: f64, c: [f64; 3], inten: f64, class: u8, seg: u32) {
        let (a, b) = self.rng.normal_pair();
        let (e, i) = self.rng.normal_pair();
        let bits = self.rng.next();
        let x = x + a * self.noise;
        if x < self.lo || x >= self.hi {
            return;
        }
        let t = &self.ctab;
        let ch = |v: f64, sh: u32| {
            let n = t[((bits >> sh) & 4095) as usize];
            ((v + n).round().clamp(0.0, 255.0) as u16) * 257
        };
        self.out.push(SynthPoint {
            x,
            y: y + b * self.noise,
            z: z + e * self.noise,
            rgb: [ch(c[0], 0), ch(c[1], 12), ch(c[2], 24)],
            intensity: (inten * (1.0 + 0.04 * i)).clamp(0.0, 65535.0) as u16,
            gps_time: x / 10.0 + 1e-4 * (bits >> 48) as f64 / 65536.0,
            class,
            segment: seg,
        });
    }
}

/// Samples a parametric surface over `u ∈ [ua, ub)` × `v ∈ [va, vb)` split into `nu × nv`
/// patches. `at(u, v)` gives the (y, z) used for the density and a weight (area element ×
/// visibility); the count per patch is `floor(λ + U)`. `f` emits each sample.
pub fn grid(
    em: &mut Em,
    (ua, ub, nu): (f64, f64, usize),
    (va, vb, nv): (f64, f64, usize),
    at: impl Fn(f64, f64) -> (f64, f64, f64),
    mut f: impl FnMut(&mut Em, f64, f64),
) {
    if ub <= ua || vb <= va {
        return;
    }
    let (du, dv) = ((ub - ua) / nu as f64, (vb - va) / nv as f64);
    for i in 0..nu {
        let u0 = ua + du * i as f64;
        for j in 0..nv {
            let v0 = va + dv * j as f64;
            let (y, z, w) = at(u0 + 0.5 * du, v0 + 0.5 * dv);
            let n = (du * dv * w * em.dens(y, z) + em.rng.u()) as u32;
            for _ in 0..n {
                let u = u0 + em.rng.u() * du;
                let v = v0 + em.rng.u() * dv;
                f(em, u, v);
            }
        }
    }
}

pub fn steps(len: f64, step: f64) -> usize {
    ((len / step).ceil() as usize).max(1)
}

pub const ASPHALT: [f64; 3] = [74.0, 74.0, 77.0];
pub const CONCRETE: [f64; 3] = [165.0, 163.0, 158.0];

/// Tile colour of a footpath at (x, y): 0.3 m tiles, light/grey per tile, darker joints.
#[inline]
pub fn tile(seed: u64, x: f64, y: f64) -> ([f64; 3], f64) {
    let (tx, ty) = (x / 0.3, y / 0.3);
    if tx - tx.floor() < 0.05 || ty - ty.floor() < 0.05 {
        return ([95.0, 93.0, 90.0], 14000.0);
    }
    let h =
        mix(seed ^ (tx.floor() as i64 as u64).wrapping_mul(0x1234_5679) ^ ty.floor() as i64 as u64);
    let l = if h & 3 == 0 { 150.0 } else { 185.0 } + ((h >> 8) & 15) as f64 - 7.5;
    ([l, l - 3.0, l - 9.0], 20000.0)
}

pub fn ground(em: &mut Em, c: &Cell, seed: u64, xa: f64, xb: f64) {
    // Carriageway with markings; cars hide the road beneath them.
    grid(
        em,
        (xa, xb, 1),
        (-ROAD_HALF, ROAD_HALF, 28),
        |x, y| (y, z_road(x, y), 1.0),
        |em, x, y| {
            if c.under_car(x, y) {
                return;
            }
            let (ay, blk) = (y.abs(), block_of(x, ROAD_BLOCK));
            let z = z_road(x, y);
            let jit = em.rng.range(-8.0, 8.0);
            let (kind, idx, mut col, mut int) = if ay < 0.06 && x.rem_euclid(DASH_PITCH) < DASH_LEN
            {
                (
                    K_DASH,
                    block_of(x, DASH_PITCH),
                    [225.0, 225.0, 220.0],
                    42000.0,
                )
            } else if (3.15..3.3).contains(&ay) {
                let k = if y > 0.0 { K_EDGE_L } else { K_EDGE_R };
                (k, blk, [225.0, 225.0, 220.0], 42000.0)
            } else {
                let k = if y > 0.0 { K_ROAD_L } else { K_ROAD_R };
                (k, blk, ASPHALT.map(|v| v + jit), 9000.0)
            };
            if c.is_wet(x, y) {
                col = [col[0] * 0.55, col[1] * 0.6, col[2] * 0.7 + 6.0];
                int *= 0.5;
            }
            let dz = if kind == K_ROAD_L || kind == K_ROAD_R {
                0.0
            } else {
                0.002
            };
            let col = c.light(x, y, col);
            em.push(x, y, z + dz, col, int, class_of(kind), sid(kind, idx));
        },
    );
    // Kerb faces (vertical, facing the road).
    for (s, kind) in [(1.0, K_KFACE_L), (-1.0, K_KFACE_R)] {
        let y = s * ROAD_HALF;
        grid(
            em,
            (xa, xb, 1),
            (0.0, KERB_H, 1),
            |x, v| (y, z_road(x, y) + v, 1.0),
            |em, x, v| {
                let col = c.light(x, y, CONCRETE);
                let seg = sid(kind, block_of(x, ROAD_BLOCK));
                em.push(x, y, z_road(x, y) + v, col, 22000.0, truth::KERB, seg);
            },
        );
    }
    // Left: kerb top, cycle path, grass, footpath. Right: kerb top, footpath.
    for (ya, yb, n) in [(ROAD_HALF, FACADE_L, 26), (FACADE_R, -ROAD_HALF, 14)] {
        grid(
            em,
            (xa, xb, 1),
            (ya, yb, n),
            |x, y| (y, z_side(x, y), 1.0),
            |em, x, y| {
                let (ay, blk) = (y.abs(), block_of(x, ROAD_BLOCK));
                let mut z = z_side(x, y);
                let (kind, col, int) = if ay < KERB_OUT {
                    let k = if y > 0.0 { K_KTOP_L } else { K_KTOP_R };
                    (k, CONCRETE, 22000.0)
                } else if y < 0.0 || ay >= GRASS_OUT {
                    let (col, int) = tile(seed, x, y);
                    (if y > 0.0 { K_FOOT_L } else { K_FOOT_R }, col, int)
                } else if ay < CYCLE_OUT {
                    let j = em.rng.range(-6.0, 6.0);
                    (K_CYCLE, [150.0 + j, 62.0 + j, 55.0 + j], 12000.0)
                } else {
                    z += grass_bump(x, y) + em.rng.range(0.0, 0.03);
                    let p = 12.0 * (0.7 * x).sin() * (1.3 * y).cos() + em.rng.range(-15.0, 15.0);
                    (K_GRASS, [70.0 + 0.5 * p, 120.0 + p, 45.0], 16000.0)
                };
                let col = c.light(x, y, col);
                em.push(x, y, z, col, int, class_of(kind), sid(kind, blk));
            },
        );
    }
}

pub fn facades(em: &mut Em, c: &Cell, xa: f64, xb: f64) {
    for b in c.left.iter().chain(c.right.iter()) {
        let (xa, xb) = (xa.max(b.xa), xb.min(b.xb));
        if xb <= xa {
            continue;
        }
        let top = b.z0 + b.h;
        let hgt = top - z_side(0.5 * (xa + xb), b.y);
        let shade = if b.left { 1.0 } else { 0.78 }; // right facades face away from the sun
        let at = |x: f64, v: f64| (b.y, z_side(x, b.y) + v, 1.0);
        grid(
            em,
            (xa, xb, 1),
            (0.0, hgt, steps(hgt, 0.5)),
            at,
            |em, x, v| {
                let z = z_side(x, b.y) + v;
                let (y, kind, idx, col, int) = match b.opening(x, z - b.z0) {
                    Opening::Wall => {
                        let j = em.rng.range(0.94, 1.06);
                        (b.plane_y(0), K_FACADE, b.gid, b.col.map(|v| v * j), 18000.0)
                    }
                    Opening::Window(w, frame) => {
                        if !frame && em.rng.u() < 0.4 {
                            return; // glass returns few echoes
                        }
                        let (col, int) = if frame {
                            (b.frame, 25000.0)
                        } else {
                            ([38.0, 48.0, 60.0], 4000.0)
                        };
                        (b.plane_y(1), K_WINDOW, b.gid * 128 + u64::from(w), col, int)
                    }
                    Opening::Door => (b.plane_y(2), K_DOOR, b.gid, b.door_col, 12000.0),
                };
                let col = col.map(|v| v * shade);
                em.push(x, y, z, col, int, truth::BUILDING, sid(kind, idx));
            },
        );
    }
}

pub fn trees(em: &mut Em, c: &Cell, xa: f64, xb: f64) {
    let h = em.h;
    for t in &c.trees {
        // Crown: ellipsoid shell with some volume scatter, sampled per x-cell.
        let (cxa, cxb) = (xa.max(t.x - t.a), xb.min(t.x + t.a));
        let q = |x: f64| (1.0 - ((x - t.x) / t.a).powi(2)).max(0.0).sqrt();
        let at = |x: f64, th: f64| {
            let (s, co) = th.sin_cos();
            let (y, z) = (t.y + t.a * q(x) * co, t.zc + t.b * q(x) * s);
            let (ty, tz) = (-y, h - z);
            let facing = (co * ty + s * tz) / (ty * ty + tz * tz).sqrt().max(1e-9);
            (y, z, 0.5 * (t.a + t.b) * (0.3 + 0.7 * facing.max(0.0)))
        };
        grid(em, (cxa, cxb, 1), (0.0, TAU, 12), at, |em, x, th| {
            let sc = q(x) * (1.0 - 0.4 * em.rng.u().powi(3));
            let (s, co) = th.sin_cos();
            let l = em.rng.range(0.7, 1.25);
            let col = t.col.map(|v| v * l);
            let seg = sid(K_CROWN, t.i);
            let (y, z) = (t.y + t.a * sc * co, t.zc + t.b * sc * s);
            em.push(x, y, z, col, 14000.0, truth::HIGH_VEGETATION, seg);
        });
        // Trunk: generated in the cell that holds its axis.
        if t.x.floor() as i64 != c.k {
            continue;
        }
        let (r, top) = (0.15, t.zc - 0.6 * t.b);
        let at = |ph: f64, z: f64| (t.y + r * ph.sin(), z, r);
        grid(
            em,
            (0.0, TAU, 8),
            (t.g, top, steps(top - t.g, 0.5)),
            at,
            |em, ph, z| {
                let (s, co) = ph.sin_cos();
                let seg = sid(K_TRUNK, t.i);
                let (x, y) = (t.x + r * co, t.y + r * s);
                em.push(
                    x,
                    y,
                    z,
                    [90.0, 65.0, 45.0],
                    10000.0,
                    truth::HIGH_VEGETATION,
                    seg,
                );
            },
        );
    }
}

pub fn poles(em: &mut Em, c: &Cell) {
    for p in &c.poles {
        let (r, top, seg, col) = (0.08, p.g + p.h, sid(K_POLE, p.i), [120.0, 125.0, 130.0]);
        let at = |ph: f64, z: f64| (p.y + r * ph.sin(), z, r);
        grid(
            em,
            (0.0, TAU, 8),
            (p.g, top, steps(p.h, 0.5)),
            at,
            |em, ph, z| {
                let (s, co) = ph.sin_cos();
                em.push(p.x + r * co, p.y + r * s, z, col, 26000.0, truth::POLE, seg);
            },
        );
        // Arm over the footpath/road, 1.5 m long, 0.3 m below the top.
        let (ra, za) = (0.05, top - 0.3);
        let at = |ph: f64, y: f64| (y, za + ra * ph.sin(), ra);
        grid(em, (0.0, TAU, 8), (p.y, p.y + 1.5, 3), at, |em, ph, y| {
            let (s, co) = ph.sin_cos();
            em.push(
                p.x + ra * co,
                y,
                za + ra * s,
                col,
                26000.0,
                truth::POLE,
                seg,
            );
        });
    }
}

pub fn cars(em: &mut Em, c: &Cell, xa: f64, xb: f64) {
    let k = c.k;
    for v in &c.cars {
        let seg = sid(K_CAR, v.i);
        let glass = [30.0, 35.0, 45.0];
        for (bx, by, bz, cab) in [
            ((v.xa, v.xb), (v.ya, v.yb), (v.zb, v.zt), false),
            ((v.cxa, v.cxb), (v.cya, v.cyb), (v.zt, v.czt), true),
        ] {
            let (fa, fb) = (xa.max(bx.0), xb.min(bx.1));
            // face: 0 top, 1 side, 2 end; cabin sides and ends are glass except the pillars.
            let emit = |em: &mut Em, x: f64, y: f64, z: f64, face: u8| {
                let inner = match face {
                    1 => (x - bx.0).min(bx.1 - x) > 0.12,
                    2 => (y - by.0).min(by.1 - y) > 0.1,
                    _ => false,
                };
                let win = cab && inner && z > bz.0 + 0.05;
                let (col, int) = if win {
                    (glass, 5000.0)
                } else {
                    (v.col, 28000.0)
                };
                em.push(x, y, z, col, int, truth::VEHICLE, seg);
            };
            // Top (the body top is hidden under the cabin).
            let at = |_x: f64, y: f64| (y, bz.1, 1.0);
            grid(em, (fa, fb, 1), (by.0, by.1, 4), at, |em, x, y| {
                let hidden = !cab && x >= v.cxa && x < v.cxb && y >= v.cya && y < v.cyb;
                if !hidden {
                    emit(em, x, y, bz.1, 0);
                }
            });
            // Side facing the sensor (+y).
            let at = |_x: f64, z: f64| (by.1, z, 1.0);
            grid(em, (fa, fb, 1), (bz.0, bz.1, 2), at, |em, x, z| {
                emit(em, x, by.1, z, 1)
            });
            // Front and back, each in the cell holding it; seen obliquely.
            for xe in [bx.0, bx.1] {
                if xe.floor() as i64 == k {
                    let at = |y: f64, z: f64| (y, z, 0.5);
                    grid(em, (by.0, by.1, 2), (bz.0, bz.1, 1), at, |em, y, z| {
                        emit(em, xe, y, z, 2)
                    });
                }
            }
        }
    }
}
