//! The scene's parameters, its ground-truth codes and the point and segment records it produces.

/// Ground-truth class codes written by the generator (ASPRS LAS 1.4 where they exist, user
/// codes ≥ 64 otherwise).
pub mod truth {
    /// High vegetation (ASPRS 5): tree crowns and tree trunks.
    pub const HIGH_VEGETATION: u8 = 5;
    /// Building (ASPRS 6): facades, windows and doors (told apart only by segment).
    pub const BUILDING: u8 = 6;
    /// Road surface (ASPRS 11): asphalt of the carriageway.
    pub const ROAD: u8 = 11;
    /// Cycle path (red asphalt).
    pub const CYCLE_PATH: u8 = 64;
    /// Tiled footpath.
    pub const FOOTPATH: u8 = 65;
    /// Kerb: vertical face and top strip.
    pub const KERB: u8 = 66;
    /// Grass / terrain.
    pub const GRASS: u8 = 67;
    /// Pole-like objects (street lights, including their arm).
    pub const POLE: u8 = 69;
    /// Vehicles (parked cars).
    pub const VEHICLE: u8 = 70;
    /// Painted lane markings (road surface, but a separate colour segment).
    pub const LANE_MARKING: u8 = 71;
}

/// Parameters of a synthetic scene.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneParams {
    /// Seed of every random choice.
    pub seed: u64,
    /// Length of the drive along x in metres (points have x in `[0, length_m)`).
    pub length_m: f64,
    /// Point density (points/m²) on a surface at 5 m from the drive line.
    pub points_per_m2: f64,
    /// Height of the sensor above the road (m).
    pub sensor_height_m: f64,
    /// Standard deviation of the isotropic Gaussian position noise (m).
    pub noise_m: f64,
    /// Standard deviation of the per-channel colour noise in 8-bit units.
    pub colour_noise: f64,
    /// Building blocks along the street.
    pub blocks: Blocks,
}

/// Building blocks: each side of the street is cut into blocks of `block_m`, filled with
/// buildings whose lengths are drawn from `min_building_m..max_building_m` (each with its own
/// colour). Long blocks of long buildings give terraces whose facades span several tiles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Blocks {
    /// Block length along x (m).
    pub block_m: f64,
    /// Shortest building (m); a block ends when less than this is left.
    pub min_building_m: f64,
    /// Longest building (m).
    pub max_building_m: f64,
}

impl Blocks {
    /// 1 ≤ min ≤ max, min ≤ block, all finite.
    pub fn is_valid(&self) -> bool {
        self.min_building_m >= 1.0
            && self.max_building_m >= self.min_building_m
            && self.block_m >= self.min_building_m
            && self.block_m.is_finite()
            && self.max_building_m.is_finite()
    }
}

impl Default for Blocks {
    /// 40 m blocks of 8–25 m buildings.
    fn default() -> Self {
        Blocks {
            block_m: 40.0,
            min_building_m: 8.0,
            max_building_m: 25.0,
        }
    }
}

impl Default for SceneParams {
    /// Seed 42, 100 m, 600 points/m² at 5 m (≈ 2.4 million points per 100 m), sensor at 2.5 m,
    /// 5 mm noise, colour noise σ = 4 (8-bit units).
    fn default() -> Self {
        SceneParams {
            seed: 42,
            length_m: 100.0,
            points_per_m2: 600.0,
            sensor_height_m: 2.5,
            noise_m: 0.005,
            colour_noise: 4.0,
            blocks: Blocks::default(),
        }
    }
}

/// One generated point. Coordinates are local metres: x along the drive (0..length_m), y across
/// (left positive), z up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SynthPoint {
    /// Along the drive (m).
    pub x: f64,
    /// Across the drive, left positive (m).
    pub y: f64,
    /// Up (m).
    pub z: f64,
    /// 16-bit colour: an 8-bit value times 257.
    pub rgb: [u16; 3],
    /// Return intensity (material dependent).
    pub intensity: u16,
    /// Time (s): x / 10 m/s plus a sub-millisecond jitter.
    pub gps_time: f64,
    /// Ground-truth class, see [`truth`].
    pub class: u8,
    /// Ground-truth segment id, see [`super::segments`].
    pub segment: u32,
}

/// Truth for one segment (ids are unique over the whole scene, > 0).
#[derive(Clone, Debug, PartialEq)]
pub struct SegmentTruth {
    /// Segment id as written in [`SynthPoint::segment`].
    pub id: u32,
    /// Class of all points of the segment.
    pub class: u8,
    /// Kind of surface: "road_left", "facade", "window", "crown", "vehicle", ...
    pub kind: &'static str,
    /// Whether the segment is a plane (then `normal`/`d` are meaningful).
    pub planar: bool,
    /// Unit normal of the plane `normal · p + d = 0` (zero when not planar).
    pub normal: [f64; 3],
    /// Offset of the plane `normal · p + d = 0`.
    pub d: f64,
    /// Smallest nominal x of the segment, clipped to the scene.
    pub x_min: f64,
    /// Largest nominal x of the segment, clipped to the scene.
    pub x_max: f64,
}
