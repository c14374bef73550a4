//! Mobile-mapping drives recorded as MCAP: `sensor_msgs/PointCloud2` in ROS 1 or ROS 2 (CDR)
//! encoding, placed in the world frame with `/tf` + `/tf_static`, `nav_msgs/Odometry` or a
//! trajectory file, and handed to the tiler.
//!
//! ```text
//! recording.mcap ──pass 1: poses──▶ TfTree (/tf, /tf_static | odometry | trajectory CSV)
//!                └─pass 2: clouds─▶ decode PointCloud2 → drop NaN / near points → pose at the
//!                                   cloud's (or each point's) time → world coordinates
//!                                   → LAS 1.4 parts (format 6, or 7 with RGB) in the run's
//!                                   work directory → the normal input set
//! ```
//! Why a temporary LAS and not a direct feed: the tiler must know each input's xy bounds
//! before reading it (a tile is complete once every input that can reach it is done), and an
//! MCAP's georeferenced extent is only known after decoding it. Writing the decoded points
//! once to uncompressed LAS parts (each part a stretch of the drive, so tiles complete as the
//! drive goes on) gives exact header bounds, keeps one reading path for all inputs, and costs
//! one sequential write and read of ~40 bytes per point.
//!
//! Modules: [`wire`] (ROS 1 / CDR primitives), [`pointcloud2`] (the cloud message and field
//! access), [`tf`] (pose messages, transform tree, interpolation), [`trajectory`] (CSV poses),
//! [`reader`] (memory-mapped, chunk-streaming MCAP access), [`fields`] (which cloud fields go
//! where in LAS), [`convert`] (the two passes, staging the inputs of a run), [`report`] (what
//! a conversion reports), [`clouds`] (pass 2: parallel placing, ordered writing), [`place`]
//! (one cloud into the world), [`parts`] (LAS parts), [`encode`] (CDR writing for the
//! simulated drive), [`mod@info`] (`tessera info`).

pub mod clouds;
pub mod convert;
pub mod encode;
pub mod fields;
pub mod guard;
pub mod info;
pub mod parts;
pub mod place;
pub mod pointcloud2;
pub mod reader;
pub mod report;
pub mod tf;
pub mod trajectory;
pub mod wire;
pub use convert::{convert_file, convert_file_with, stage_inputs, Conversion, StagedInputs};
pub use info::{info, McapInfo};
pub use reader::McapSource;
pub use report::McapReport;

mod params;
pub use fields::{SCAN_SEGMENT, SCAN_SEGMENT_BITS};
pub use params::*;
