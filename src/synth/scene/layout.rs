//! Layout of the street: constants, surfaces, planes, segment kinds, RNG and the objects placed
//! on lattices along x.

use super::truth;

// ---------------------------------------------------------------------------------------------
// Layout constants.

pub const GRADE: f64 = 0.005; // road grade along x
pub const FALL: f64 = 0.02; // road cross-fall from the centre line
pub const SIDE_FALL: f64 = 0.01; // footpath/cycle path cross-fall towards the road
pub const ROAD_HALF: f64 = 3.5;
pub const KERB_H: f64 = 0.12;
pub const KERB_OUT: f64 = 3.65;
pub const CYCLE_OUT: f64 = 5.65;
pub const GRASS_OUT: f64 = 7.5;
pub const FACADE_L: f64 = 10.0;
pub const FACADE_R: f64 = -7.0;
pub const WIN_RECESS: f64 = 0.1;
pub const DOOR_RECESS: f64 = 0.15;
pub const ROAD_BLOCK: f64 = 60.0;
pub const DASH_PITCH: f64 = 9.0;
pub const DASH_LEN: f64 = 3.0;
pub const TREE_PITCH: f64 = 12.0;
pub const POLE_PITCH: f64 = 25.0;
pub const CAR_PITCH: f64 = 10.0;
pub const WET_PITCH: f64 = 15.0;
pub const SUN: (f64, f64) = (0.25, 0.6); // ground shadow displacement per metre of height (x, y)

/// Road surface height (crowned at y = 0).
#[inline]
pub fn z_road(x: f64, y: f64) -> f64 {
    GRADE * x - FALL * y.abs()
}

/// Height of kerb top, cycle path and footpaths (|y| ≥ 3.5).
#[inline]
pub fn z_side(x: f64, y: f64) -> f64 {
    GRADE * x - FALL * ROAD_HALF + KERB_H + SIDE_FALL * (y.abs() - KERB_OUT).max(0.0)
}

/// Gentle undulation of the grass strip.
#[inline]
pub fn grass_bump(x: f64, y: f64) -> f64 {
    0.03 * (0.9 * x + 1.7 * y).sin() + 0.015 * (2.3 * x - 0.7 * y).sin()
}

// Segment kinds: id = kind << 26 | index.
pub const KINDS: [(&str, u8); 20] = [
    ("road_left", truth::ROAD),
    ("road_right", truth::ROAD),
    ("marking_centre", truth::LANE_MARKING),
    ("marking_edge_left", truth::LANE_MARKING),
    ("marking_edge_right", truth::LANE_MARKING),
    ("kerb_face_left", truth::KERB),
    ("kerb_top_left", truth::KERB),
    ("kerb_face_right", truth::KERB),
    ("kerb_top_right", truth::KERB),
    ("cycle_path", truth::CYCLE_PATH),
    ("grass", truth::GRASS),
    ("footpath_left", truth::FOOTPATH),
    ("footpath_right", truth::FOOTPATH),
    ("facade", truth::BUILDING),
    ("window", truth::BUILDING),
    ("door", truth::BUILDING),
    ("trunk", truth::HIGH_VEGETATION),
    ("crown", truth::HIGH_VEGETATION),
    ("pole", truth::POLE),
    ("vehicle", truth::VEHICLE),
];
pub const K_ROAD_L: u32 = 1;
pub const K_ROAD_R: u32 = 2;
pub const K_DASH: u32 = 3;
pub const K_EDGE_L: u32 = 4;
pub const K_EDGE_R: u32 = 5;
pub const K_KFACE_L: u32 = 6;
pub const K_KTOP_L: u32 = 7;
pub const K_KFACE_R: u32 = 8;
pub const K_KTOP_R: u32 = 9;
pub const K_CYCLE: u32 = 10;
pub const K_GRASS: u32 = 11;
pub const K_FOOT_L: u32 = 12;
pub const K_FOOT_R: u32 = 13;
pub const K_FACADE: u32 = 14;
pub const K_WINDOW: u32 = 15;
pub const K_DOOR: u32 = 16;
pub const K_TRUNK: u32 = 17;
pub const K_CROWN: u32 = 18;
pub const K_POLE: u32 = 19;
pub const K_CAR: u32 = 20;
// RNG stream kinds that are not segments.
pub const R_CELL: u64 = 100;
pub const R_BLOCK: u64 = 101;
pub const R_WET: u64 = 103;

#[inline]
pub fn sid(kind: u32, idx: u64) -> u32 {
    (kind << 26) | (idx as u32 & 0x03FF_FFFF)
}

#[inline]
pub fn class_of(kind: u32) -> u8 {
    KINDS[(kind - 1) as usize].1
}

/// Index of the lattice block containing x (never negative).
#[inline]
pub fn block_of(x: f64, pitch: f64) -> u64 {
    (x / pitch).floor().max(0.0) as u64
}

/// Unit plane `n · p + d = 0` from unnormalised coefficients.
pub fn plane(a: f64, b: f64, c: f64, d: f64) -> ([f64; 3], f64) {
    let n = (a * a + b * b + c * c).sqrt();
    ([a / n, b / n, c / n], d / n)
}

/// Plane of a segment kind of the ground layout (`None` for non-planar kinds).
pub fn ground_plane(kind: u32) -> Option<([f64; 3], f64)> {
    let c0 = -FALL * ROAD_HALF + KERB_H; // kerb top height at x = 0
    let c1 = c0 - SIDE_FALL * KERB_OUT;
    Some(match kind {
        K_ROAD_L => plane(-GRADE, FALL, 1.0, 0.0),
        K_ROAD_R => plane(-GRADE, -FALL, 1.0, 0.0),
        K_DASH => plane(-GRADE, 0.0, 1.0, -0.0014),
        K_EDGE_L => plane(-GRADE, FALL, 1.0, -0.002),
        K_EDGE_R => plane(-GRADE, -FALL, 1.0, -0.002),
        K_KFACE_L => ([0.0, -1.0, 0.0], ROAD_HALF),
        K_KFACE_R => ([0.0, 1.0, 0.0], ROAD_HALF),
        K_KTOP_L | K_KTOP_R => plane(-GRADE, 0.0, 1.0, -c0),
        K_CYCLE | K_FOOT_L => plane(-GRADE, -SIDE_FALL, 1.0, -c1),
        K_FOOT_R => plane(-GRADE, SIDE_FALL, 1.0, -c1),
        _ => return None,
    })
}

// ---------------------------------------------------------------------------------------------
// Random numbers.

#[inline]
pub fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[inline]
pub fn hash(seed: u64, kind: u64, idx: i64) -> u64 {
    mix(mix(seed ^ mix(kind)) ^ idx as u64)
}

pub use crate::rng::Rng;

// ---------------------------------------------------------------------------------------------
// Objects on lattices along x.

#[derive(Clone, Copy, Debug)]
pub struct Building {
    pub gid: u64,
    pub left: bool,
    pub xa: f64,
    pub xb: f64,
    pub y: f64,
    pub z0: f64,
    pub h: f64,
    pub col: [f64; 3],
    pub frame: [f64; 3],
    pub door_col: [f64; 3],
    pub wx0: f64,
    pub pitch: f64,
    pub ww: f64,
    pub wh: f64,
    pub sill: f64,
    pub fh: f64,
    pub cols: u32,
    pub floors: u32,
    pub door: u32,
    pub dxa: f64,
    pub dxb: f64,
    pub dh: f64,
}

pub enum Opening {
    Wall,
    Window(u32, bool),
    Door,
}

impl Building {
    /// Plane offset of facade (0), window (1) or door (2): the plane is y = ±offset.
    #[inline]
    pub fn plane_y(&self, what: u8) -> f64 {
        let r = [0.0, WIN_RECESS, DOOR_RECESS][what as usize];
        if self.left {
            self.y + r
        } else {
            self.y - r
        }
    }
    #[inline]
    pub fn window_x(&self, c: u32) -> f64 {
        self.wx0 + c as f64 * self.pitch
    }
    /// What lies at facade position x, height v above `z0`.
    #[inline]
    pub fn opening(&self, x: f64, v: f64) -> Opening {
        if x >= self.dxa && x < self.dxb && v < self.dh {
            return Opening::Door;
        }
        let c = ((x - self.wx0) / self.pitch).floor();
        let f = (v / self.fh).floor();
        if c < 0.0 || f < 0.0 || c >= self.cols as f64 || f >= self.floors as f64 {
            return Opening::Wall;
        }
        let (c, f) = (c as u32, f as u32);
        let lx = x - self.window_x(c);
        let lz = v - f as f64 * self.fh - self.sill;
        if lx >= self.ww || !(0.0..self.wh).contains(&lz) || (f == 0 && c == self.door) {
            return Opening::Wall;
        }
        let fw = 0.07;
        let frame = lx < fw
            || lx > self.ww - fw
            || lz < fw
            || lz > self.wh - fw
            || (lx - 0.5 * self.ww).abs() < 0.5 * fw;
        Opening::Window(f * 16 + c, frame)
    }
}

pub const FACADE_COLOURS: [[f64; 3]; 5] = [
    [150.0, 70.0, 55.0],
    [215.0, 195.0, 160.0],
    [235.0, 235.0, 228.0],
    [140.0, 140.0, 140.0],
    [200.0, 170.0, 110.0],
];

/// Buildings of one block (default 40 m) on one side (up to 8, separated by alleys or
/// adjoining), lengths drawn from `blocks`.
pub fn block_buildings(
    seed: u64,
    left: bool,
    b: i64,
    blocks: &super::Blocks,
    out: &mut Vec<Building>,
) {
    if b < 0 {
        return;
    }
    let side = u64::from(left);
    let mut r = Rng(hash(seed, R_BLOCK + 10 * side, b));
    let x_end = (b + 1) as f64 * blocks.block_m;
    let mut x = b as f64 * blocks.block_m + r.range(0.0, 3.0);
    for j in 0..8u64 {
        let len = r
            .range(blocks.min_building_m, blocks.max_building_m)
            .min(x_end - x);
        if len < blocks.min_building_m {
            break;
        }
        let y = if left { FACADE_L } else { FACADE_R };
        let h = r.range(8.0, 20.0);
        let base = FACADE_COLOURS[r.below(5) as usize];
        let jit = r.range(0.9, 1.08);
        let col = [base[0] * jit, base[1] * jit, base[2] * jit];
        let fh = r.range(2.8, 3.4);
        let pitch = r.range(2.2, 3.5);
        let ww = pitch * r.range(0.4, 0.6);
        let wh = r.range(1.2, 1.7);
        let sill = r.range(0.8, 1.0);
        let cols = (((len - 0.8) / pitch).floor() as u32).clamp(1, 15);
        let floors = ((((h - sill - wh - 0.5) / fh).floor() + 1.0) as u32).clamp(1, 7);
        let wx0 = x + 0.5 * (len - cols as f64 * pitch) + 0.5 * (pitch - ww);
        let door = r.below(cols);
        let dw = r.range(1.0, 1.6).min(pitch - 0.2);
        let dc = wx0 + door as f64 * pitch + 0.5 * ww;
        let frame = if r.u() < 0.6 { [230.0; 3] } else { [55.0; 3] };
        let door_col = if r.u() < 0.5 {
            [100.0, 62.0, 38.0]
        } else {
            [45.0, 42.0, 42.0]
        };
        out.push(Building {
            gid: (b as u64 * 2 + side) * 8 + j,
            left,
            xa: x,
            xb: x + len,
            y,
            z0: z_side(x, y),
            h,
            col,
            frame,
            door_col,
            wx0,
            pitch,
            ww,
            wh,
            sill,
            fh,
            cols,
            floors,
            door,
            dxa: dc - 0.5 * dw,
            dxb: dc + 0.5 * dw,
            dh: r.range(2.2, 2.5),
        });
        x += len + if r.u() < 0.55 { 0.0 } else { r.range(1.5, 5.0) };
    }
}

#[derive(Clone, Copy, Debug)]
pub struct Tree {
    pub i: u64,
    pub x: f64,
    pub y: f64,
    pub g: f64,
    pub a: f64,
    pub b: f64,
    pub zc: f64,
    pub col: [f64; 3],
}

pub fn tree(seed: u64, i: i64) -> Option<Tree> {
    let mut r = Rng(hash(seed, u64::from(K_TRUNK), i));
    if i < 0 || r.u() < 0.1 {
        return None;
    }
    let x = i as f64 * TREE_PITCH + 6.0 + r.range(-2.5, 2.5);
    let y = 0.5 * (CYCLE_OUT + GRASS_OUT) + r.range(-0.3, 0.3);
    let g = z_side(x, y) + grass_bump(x, y);
    let a = r.range(1.5, 3.0);
    let b = a * r.range(0.9, 1.4);
    let zc = g + r.range(2.0, 3.5) + b;
    let col = [
        r.range(45.0, 85.0),
        r.range(90.0, 140.0),
        r.range(30.0, 60.0),
    ];
    Some(Tree {
        i: i as u64,
        x,
        y,
        g,
        a,
        b,
        zc,
        col,
    })
}

#[derive(Clone, Copy, Debug)]
pub struct Pole {
    pub i: u64,
    pub x: f64,
    pub y: f64,
    pub g: f64,
    pub h: f64,
}

pub fn pole(seed: u64, i: i64) -> Option<Pole> {
    let mut r = Rng(hash(seed, u64::from(K_POLE), i));
    if i < 0 {
        return None;
    }
    let x = i as f64 * POLE_PITCH + 12.5 + r.range(-1.0, 1.0);
    let y = -4.0 + r.range(-0.05, 0.05);
    Some(Pole {
        i: i as u64,
        x,
        y,
        g: z_side(x, y),
        h: r.range(5.0, 8.0),
    })
}

#[derive(Clone, Copy, Debug)]
pub struct Car {
    pub i: u64,
    pub xa: f64,
    pub xb: f64,
    pub ya: f64,
    pub yb: f64,
    pub zb: f64,
    pub zt: f64,
    pub cxa: f64,
    pub cxb: f64,
    pub cya: f64,
    pub cyb: f64,
    pub czt: f64,
    pub col: [f64; 3],
}

pub const CAR_COLOURS: [[f64; 3]; 6] = [
    [230.0, 230.0, 232.0],
    [25.0, 25.0, 28.0],
    [170.0, 172.0, 175.0],
    [170.0, 30.0, 30.0],
    [40.0, 60.0, 140.0],
    [100.0, 100.0, 105.0],
];

pub fn car(seed: u64, i: i64) -> Option<Car> {
    let mut r = Rng(hash(seed, u64::from(K_CAR), i));
    if i < 0 || r.u() < 0.25 {
        return None;
    }
    let len = r.range(3.8, 5.0);
    let w = r.range(1.65, 1.8);
    let xc = i as f64 * CAR_PITCH + 5.0 + r.range(-1.0, 1.0) * (4.7 - 0.5 * len);
    let ya = -3.3 + r.u() * (1.8 - w);
    let zb = z_road(xc, ya + 0.5 * w) + 0.3;
    let zt = zb + r.range(0.6, 0.8);
    let cl = len * r.range(0.5, 0.6);
    let cxa = xc - 0.5 * cl - r.range(0.0, 0.3);
    Some(Car {
        i: i as u64,
        xa: xc - 0.5 * len,
        xb: xc + 0.5 * len,
        ya,
        yb: ya + w,
        zb,
        zt,
        cxa,
        cxb: cxa + cl,
        cya: ya + 0.1,
        cyb: ya + w - 0.1,
        czt: zt + r.range(0.45, 0.6),
        col: CAR_COLOURS[r.below(6) as usize],
    })
}

#[derive(Clone, Copy, Debug)]
pub struct Wet {
    pub x: f64,
    pub y: f64,
    pub rx: f64,
    pub ry: f64,
}

pub fn wet(seed: u64, j: i64) -> Option<Wet> {
    let mut r = Rng(hash(seed, R_WET, j));
    if r.u() < 0.6 {
        return None;
    }
    Some(Wet {
        x: (j as f64 + r.u()) * WET_PITCH,
        y: r.range(-3.0, 3.0),
        rx: r.range(1.0, 4.0),
        ry: r.range(0.5, 1.5),
    })
}

// ---------------------------------------------------------------------------------------------
// Per-cell context.

/// Objects relevant to one 1 m cell.
#[derive(Default)]
pub struct Cell {
    pub k: i64,
    pub left: Vec<Building>,
    pub right: Vec<Building>, // includes buildings whose shadow reaches the cell
    pub trees: Vec<Tree>,
    pub poles: Vec<Pole>,
    pub cars: Vec<Car>,
    pub wet: Vec<Wet>,
}

/// Small cache of building blocks (generated once per slab, not per cell).
pub struct World {
    pub seed: u64,
    pub blocks: super::Blocks,
    pub cache: Vec<(bool, i64, Vec<Building>)>,
}

impl World {
    pub fn block(&mut self, left: bool, b: i64) -> &[Building] {
        let pos = match self.cache.iter().position(|e| e.0 == left && e.1 == b) {
            Some(p) => p,
            None => {
                let mut v = Vec::new();
                block_buildings(self.seed, left, b, &self.blocks, &mut v);
                if self.cache.len() >= 8 {
                    self.cache.remove(0);
                }
                self.cache.push((left, b, v));
                self.cache.len() - 1
            }
        };
        &self.cache[pos].2
    }

    pub fn fill(&mut self, k: i64, c: &mut Cell) {
        let (x0, x1) = (k as f64, k as f64 + 1.0);
        let s = self.seed;
        c.k = k;
        c.left.clear();
        c.right.clear();
        let lat = |lo: f64, hi: f64, p: f64| (lo / p).floor() as i64..=(hi / p).floor() as i64;
        for left in [true, false] {
            let reach = if left { 0.0 } else { 8.0 };
            for b in lat(x0 - reach, x1, self.blocks.block_m) {
                let v: Vec<Building> = (self.block(left, b).iter())
                    .filter(|g| g.xb > x0 - reach && g.xa < x1)
                    .copied()
                    .collect();
                let dst = if left { &mut c.left } else { &mut c.right };
                dst.extend(v);
            }
        }
        c.trees.clear();
        c.trees
            .extend(lat(x0 - 12.0, x1 + 12.0, TREE_PITCH).filter_map(|i| tree(s, i)));
        c.poles.clear();
        c.poles.extend(
            lat(x0 - 2.0, x1 + 2.0, POLE_PITCH)
                .filter_map(|i| pole(s, i))
                .filter(|p| p.x.floor() as i64 == k),
        );
        c.cars.clear();
        c.cars.extend(
            lat(x0 - 6.0, x1 + 6.0, CAR_PITCH)
                .filter_map(|i| car(s, i))
                .filter(|v| v.xb > x0 - 1.0 && v.xa < x1 + 1.0),
        );
        c.wet.clear();
        c.wet
            .extend(lat(x0 - 5.0, x1 + 5.0, WET_PITCH).filter_map(|j| wet(s, j)));
    }
}

impl Cell {
    #[inline]
    pub fn under_car(&self, x: f64, y: f64) -> bool {
        (self.cars.iter()).any(|c| x >= c.xa && x < c.xb && y >= c.ya && y < c.yb)
    }
    #[inline]
    pub fn is_wet(&self, x: f64, y: f64) -> bool {
        (self.wet.iter()).any(|w| ((x - w.x) / w.rx).powi(2) + ((y - w.y) / w.ry).powi(2) < 1.0)
    }
    /// Whether ground point (x, y) lies in the shadow of a right-hand building or a tree crown.
    #[inline]
    pub fn shadow(&self, x: f64, y: f64) -> bool {
        let t = (y - FACADE_R) / SUN.1;
        let xs = x - SUN.0 * t;
        if (self.right.iter()).any(|b| t <= b.h && xs >= b.xa && xs < b.xb) {
            return true;
        }
        self.trees.iter().any(|tr| {
            let hz = tr.zc - tr.g;
            let dx = x - tr.x - SUN.0 * hz;
            let dy = y - tr.y - SUN.1 * hz;
            dx * dx + dy * dy < 0.7 * tr.a * tr.a
        })
    }
    /// Colour and intensity factors for ground lighting (shadow is darker and bluish).
    #[inline]
    pub fn light(&self, x: f64, y: f64, c: [f64; 3]) -> [f64; 3] {
        if self.shadow(x, y) {
            [c[0] * 0.48, c[1] * 0.52, c[2] * 0.6]
        } else {
            c
        }
    }
}
