//! Deterministic synthetic scenes with reference plane ids, and Hoover-style scoring
//! (thesis §5.2).

/// Small deterministic generator (PCG-style LCG + Box–Muller).
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    pub fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn normal(&mut self) -> f64 {
        let u = self.uniform().max(1e-12);
        let v = self.uniform();
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// A coloured point cloud with a reference plane id (1-based) per point.
#[derive(Default, Clone)]
pub struct Scene {
    pub xyz: Vec<[f64; 3]>,
    pub rgb: Vec<[u16; 3]>,
    pub refid: Vec<u32>,
    /// Reference unit normal per plane id (index id − 1).
    pub normals: Vec<[f64; 3]>,
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

/// Surface patch: points `o + s·u + t·v` for (s, t) in [0, su] × [0, tv] where `keep(s, t)`
/// says which reference plane (if any) the point belongs to and its colour.
pub struct Patch<'a> {
    pub o: [f64; 3],
    pub u: [f64; 3],
    pub v: [f64; 3],
    pub su: f64,
    pub tv: f64,
    /// (s, t) → Some((plane key, rgb 0–255)) or None (hole).
    pub f: &'a dyn Fn(f64, f64) -> Option<(usize, [f64; 3])>,
}

pub struct Builder {
    pub scene: Scene,
    pub rng: Rng,
    pub density: f64,
    pub noise_m: f64,
    pub colour_noise: f64,
    pub offset: [f64; 3],
}

impl Builder {
    pub fn new(seed: u64, density: f64, noise_m: f64) -> Self {
        Builder {
            scene: Scene::default(),
            rng: Rng::new(seed),
            density,
            noise_m,
            colour_noise: 6.0,
            offset: [512_345.0, 5_401_234.0, 31.0],
        }
    }

    /// Adds a patch; plane keys (1-based) are the reference plane ids.
    pub fn patch(&mut self, p: &Patch<'_>) {
        let u = unit(p.u);
        let v = unit(p.v);
        let n = unit(cross(u, v));
        let count = (p.su * p.tv * self.density).round() as usize;
        for _ in 0..count {
            let s = self.rng.uniform() * p.su;
            let t = self.rng.uniform() * p.tv;
            let Some((key, col)) = (p.f)(s, t) else {
                continue;
            };
            // Plane keys are the reference ids.
            let id = key;
            if self.scene.normals.len() < key {
                self.scene.normals.resize(key, [0.0, 0.0, 1.0]);
            }
            self.scene.normals[key - 1] = n;
            let xyz: [f64; 3] = std::array::from_fn(|c| {
                p.o[c] + s * u[c] + t * v[c] + self.noise_m * self.rng.normal() + self.offset[c]
            });
            let rgb: [u16; 3] = std::array::from_fn(|c| {
                let x = col[c] + (self.rng.uniform() * 2.0 - 1.0) * self.colour_noise;
                x.round().clamp(0.0, 255.0) as u16
            });
            self.scene.xyz.push(xyz);
            self.scene.rgb.push(rgb);
            self.scene.refid.push(id as u32);
        }
    }
}

/// A gabled house (10 × 8 m, 5 m eaves, 35° roof) on a ground ring, with three windows and a
/// door in the walls, a shadow on part of the south wall, and a dormer (front, two sides, flat
/// roof) on the south roof facet. Plane keys: 1 ground, 2–5 walls, 6–8 windows, 9 door,
/// 10–11 roof facets, 12 dormer roof, 13 dormer front, 14–15 dormer sides.
pub fn house(seed: u64, density: f64, noise_m: f64) -> Builder {
    let mut b = Builder::new(seed, density, noise_m);
    let (w, d, h) = (10.0, 8.0, 5.0);
    let slope = 35f64.to_radians().tan();
    let ridge = h + d / 2.0 * slope;
    let wall = [205.0, 185.0, 150.0];
    let glass = [60.0, 75.0, 100.0];
    let door = [110.0, 62.0, 30.0];
    let tiles = [170.0, 62.0, 45.0];
    let grass = [70.0, 130.0, 55.0];
    let white = [232.0, 230.0, 222.0];
    let lead = [115.0, 118.0, 125.0];
    // Ground ring, 1 m wide.
    b.patch(&Patch {
        o: [-1.0, -1.0, 0.0],
        u: [1.0, 0.0, 0.0],
        v: [0.0, 1.0, 0.0],
        su: w + 2.0,
        tv: d + 2.0,
        f: &|s, t| {
            let inside = s > 1.0 && s < w + 1.0 && t > 1.0 && t < d + 1.0;
            (!inside).then_some((1, grass))
        },
    });
    // South wall (y = 0), windows 6, 7 and door 9, shadow on its east end (soft edge).
    b.patch(&Patch {
        o: [0.0, 0.0, 0.0],
        u: [1.0, 0.0, 0.0],
        v: [0.0, 0.0, 1.0],
        su: w,
        tv: h,
        f: &|s, t| {
            let shade = 1.0 - 0.2 * ((s - 8.0) / 0.8).clamp(0.0, 1.0);
            let c = |c: [f64; 3]| c.map(|x| x * shade);
            if (1.5..2.7).contains(&s) && (1.5..2.8).contains(&t) {
                Some((6, c(glass)))
            } else if (6.8..8.0).contains(&s) && (1.5..2.8).contains(&t) {
                Some((7, c(glass)))
            } else if (4.3..5.3).contains(&s) && t < 2.1 {
                Some((9, c(door)))
            } else {
                Some((2, c(wall)))
            }
        },
    });
    // North wall (y = d), window 8.
    b.patch(&Patch {
        o: [0.0, d, 0.0],
        u: [1.0, 0.0, 0.0],
        v: [0.0, 0.0, 1.0],
        su: w,
        tv: h,
        f: &|s, t| {
            if (4.0..5.5).contains(&s) && (1.5..2.8).contains(&t) {
                Some((8, glass))
            } else {
                Some((3, wall))
            }
        },
    });
    // Gable walls (x = 0, x = w): rectangle plus triangle.
    for (x, key) in [(0.0, 4), (w, 5)] {
        b.patch(&Patch {
            o: [x, 0.0, 0.0],
            u: [0.0, 1.0, 0.0],
            v: [0.0, 0.0, 1.0],
            su: d,
            tv: ridge,
            f: &move |s, t| {
                let top = h + (d / 2.0 - (s - d / 2.0).abs()) * slope;
                (t <= top).then_some((key, wall))
            },
        });
    }
    // Dormer on the south facet: x in [3.5, 5.5], front at y = 1.2, flat roof at z = zr.
    let (dx0, dx1, dy0, zr) = (3.5, 5.5, 1.2, 6.9);
    let dy1 = (zr - h) / slope;
    let on_dormer = move |x: f64, y: f64| (dx0..dx1).contains(&x) && (dy0..dy1).contains(&y);
    // Roof facets, sampled along the slope.
    let run = d / 2.0;
    let len = (run * run + (run * slope).powi(2)).sqrt();
    b.patch(&Patch {
        o: [0.0, 0.0, h],
        u: [1.0, 0.0, 0.0],
        v: [0.0, run, run * slope],
        su: w,
        tv: len,
        f: &|s, t| {
            let y = t / len * run;
            (!on_dormer(s, y)).then_some((10, tiles))
        },
    });
    b.patch(&Patch {
        o: [0.0, d, h],
        u: [1.0, 0.0, 0.0],
        v: [0.0, -run, run * slope],
        su: w,
        tv: len,
        f: &|_, _| Some((11, tiles)),
    });
    b.patch(&Patch {
        o: [dx0, dy0, zr],
        u: [1.0, 0.0, 0.0],
        v: [0.0, 1.0, 0.0],
        su: dx1 - dx0,
        tv: dy1 - dy0,
        f: &|_, _| Some((12, lead)),
    });
    let zf = h + dy0 * slope;
    b.patch(&Patch {
        o: [dx0, dy0, zf],
        u: [1.0, 0.0, 0.0],
        v: [0.0, 0.0, 1.0],
        su: dx1 - dx0,
        tv: zr - zf,
        f: &|_, _| Some((13, white)),
    });
    for (x, key) in [(dx0, 14), (dx1, 15)] {
        b.patch(&Patch {
            o: [x, dy0, zf],
            u: [0.0, 1.0, 0.0],
            v: [0.0, 0.0, 1.0],
            su: dy1 - dy0,
            tv: zr - zf,
            f: &move |s, t| (zf + t >= h + (dy0 + s) * slope).then_some((key, white)),
        });
    }
    b
}

/// Scores of a segmentation against reference plane ids at tolerance `tol`.
#[derive(Debug)]
pub struct Score {
    /// Reference planes.
    pub planes: usize,
    /// Reference planes with ≥ tol of their points in one segment that is ≥ tol theirs.
    pub recovered: usize,
    /// Result segments holding ≥ tol of two or more reference planes.
    pub under: usize,
    /// RMSE of the angle between each recovered plane's reference and result normal, degrees.
    pub angle_rmse_deg: f64,
    /// Per reference plane: (id, size, best segment, share of plane, share of segment).
    pub detail: Vec<(u32, usize, u32, f64, f64)>,
}

pub fn score(scene: &Scene, out: &tessera::segment::SegOutput, tol: f64) -> Score {
    use std::collections::HashMap;
    let nref = scene.normals.len();
    let mut inter: HashMap<(u32, u32), usize> = HashMap::new();
    let mut rsize = vec![0usize; nref + 1];
    let mut ssize: HashMap<u32, usize> = HashMap::new();
    for (r, &l) in scene.refid.iter().zip(&out.labels) {
        rsize[*r as usize] += 1;
        *ssize.entry(l).or_default() += 1;
        *inter.entry((*r, l)).or_default() += 1;
    }
    let mut recovered = 0;
    let mut se = 0.0;
    let mut detail = Vec::new();
    let mut full: HashMap<u32, usize> = HashMap::new();
    for r in 1..=nref as u32 {
        let (best, nbest) = inter
            .iter()
            .filter(|((rr, l), _)| *rr == r && *l != 0)
            .map(|((_, l), &c)| (*l, c))
            .max_by_key(|&(l, c)| (c, std::cmp::Reverse(l)))
            .unwrap_or((0, 0));
        let mr = nbest as f64 / rsize[r as usize].max(1) as f64;
        let mo = nbest as f64 / ssize.get(&best).copied().unwrap_or(1).max(1) as f64;
        detail.push((r, rsize[r as usize], best, mr, mo));
        if mr >= tol && best != 0 {
            *full.entry(best).or_default() += 1;
        }
        if mr >= tol && mo >= tol {
            recovered += 1;
            let n = out.segments[best as usize - 1].normal;
            let t = scene.normals[r as usize - 1];
            let c = (n[0] * t[0] + n[1] * t[1] + n[2] * t[2]).abs().min(1.0);
            se += c.acos().to_degrees().powi(2);
        }
    }
    let under = full.values().filter(|&&c| c >= 2).count();
    Score {
        planes: nref,
        recovered,
        under,
        angle_rmse_deg: (se / recovered.max(1) as f64).sqrt(),
        detail,
    }
}
