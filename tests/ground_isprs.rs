//! ISPRS WG III/3 filter test: each of the 15 reference samples filtered on its own with the
//! default parameters. Gate: mean total error ≤ 5.0 % and mean kappa ≥ 84 %.

mod common;

use tessera::eval::ground::score_ground;
use tessera::ground::{classify_ground, GroundClass, GroundParams};

#[test]
fn isprs_samples_meet_gate() {
    let params = GroundParams::default();
    let mut totals = Vec::new();
    let mut kappas = Vec::new();
    println!(
        "{:<8} {:>7} {:>8} {:>8} {:>8} {:>8}",
        "sample", "points", "TypeI%", "TypeII%", "total%", "kappa%"
    );
    for name in common::ISPRS_SAMPLES {
        let Some(path) = common::data_file(&format!("isprs-filtertest/{name}-utm.laz")) else {
            return;
        };
        let (xyz, class) = match common::read_las(&path) {
            Ok(v) => v,
            Err(e) => panic!("{e}"),
        };
        let reference: Vec<bool> = class.iter().map(|&c| c == 2).collect();
        let result = match classify_ground(&xyz, &params) {
            Ok(r) => r,
            Err(e) => panic!("{name}: {e}"),
        };
        let is_ground: Vec<bool> = result.iter().map(|c| *c == GroundClass::Ground).collect();
        let s = score_ground(&reference, &is_ground);
        println!(
            "{:<8} {:>7} {:>8.2} {:>8.2} {:>8.2} {:>8.2}",
            name,
            xyz.len(),
            s.type1,
            s.type2,
            s.total,
            s.kappa
        );
        totals.push(s.total);
        kappas.push(s.kappa);
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (mt, mk) = (mean(&totals), mean(&kappas));
    println!("mean total {mt:.2} %, mean kappa {mk:.2} % (params {params:?})");
    assert!(mt <= 5.0, "mean total error {mt:.2} % > 5.0 %");
    assert!(mk >= 84.0, "mean kappa {mk:.2} % < 84 %");
}
