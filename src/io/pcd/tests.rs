//! PCD fixtures written here, with values known exactly, in all three data modes.

use super::*;

/// One test point: every field of the fixture layout.
#[derive(Clone)]
struct P {
    xyz: [f32; 3],
    rgba: u32,
    intensity: f32,
    label: u32,
    normal: [f32; 3],
    time: f64,
    ring: i16,
}

const FIELDS: &str = "FIELDS x y z rgba intensity label normal _ gps_time ring\n\
                      SIZE 4 4 4 4 4 4 4 1 8 2\n\
                      TYPE F F F U F U F U F I\n\
                      COUNT 1 1 1 1 1 1 3 3 1 1\n";

fn points(n: usize) -> Vec<P> {
    (0..n)
        .map(|i| {
            let f = i as f32;
            P {
                xyz: [1000.25 + f * 0.5, -3.125 * f, 0.001 * f * f],
                rgba: 0xff00_0000
                    | (((i as u32 * 37) % 256) << 16)
                    | (((i as u32 * 91) % 256) << 8)
                    | ((i as u32 * 13) % 256),
                intensity: 0.1 * f,
                label: (i as u32 * 7919) % 100_003,
                normal: [0.0, (f * 0.3).sin(), (f * 0.3).cos()],
                time: 1.7e9 + i as f64 * 1e-6,
                ring: (i as i16 % 64) - 32,
            }
        })
        .collect()
}

/// Little-endian bytes of each field of one point, in field order.
fn field_bytes(p: &P) -> Vec<Vec<u8>> {
    let cat = |parts: &[&[u8]]| parts.concat();
    vec![
        p.xyz[0].to_le_bytes().to_vec(),
        p.xyz[1].to_le_bytes().to_vec(),
        p.xyz[2].to_le_bytes().to_vec(),
        p.rgba.to_le_bytes().to_vec(),
        p.intensity.to_le_bytes().to_vec(),
        p.label.to_le_bytes().to_vec(),
        cat(&[
            &p.normal[0].to_le_bytes(),
            &p.normal[1].to_le_bytes(),
            &p.normal[2].to_le_bytes(),
        ]),
        vec![0xaa, 0xbb, 0xcc],
        p.time.to_le_bytes().to_vec(),
        p.ring.to_le_bytes().to_vec(),
    ]
}

fn header(n: usize, mode: &str) -> String {
    format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n{FIELDS}WIDTH {n}\nHEIGHT 1\n\
         VIEWPOINT 1 2 3 1 0 0 0\nPOINTS {n}\nDATA {mode}\n"
    )
}

fn binary(pts: &[P]) -> Vec<u8> {
    let mut out = header(pts.len(), "binary").into_bytes();
    for p in pts {
        out.extend(field_bytes(p).concat());
    }
    out
}

fn compressed(pts: &[P]) -> Vec<u8> {
    let per_point: Vec<Vec<Vec<u8>>> = pts.iter().map(field_bytes).collect();
    let mut raw = Vec::new();
    for f in 0..10 {
        for p in &per_point {
            raw.extend_from_slice(&p[f]);
        }
    }
    let packed = lzf::compress(&raw);
    let mut out = header(pts.len(), "binary_compressed").into_bytes();
    out.extend((packed.len() as u32).to_le_bytes());
    out.extend((raw.len() as u32).to_le_bytes());
    out.extend(packed);
    out
}

fn ascii(pts: &[P]) -> Vec<u8> {
    let mut out = header(pts.len(), "ascii");
    for (i, p) in pts.iter().enumerate() {
        // Irregular whitespace, as in real files.
        let sep = if i % 2 == 0 { " " } else { "  \t " };
        let vals = [
            p.xyz[0].to_string(),
            p.xyz[1].to_string(),
            p.xyz[2].to_string(),
            p.rgba.to_string(),
            p.intensity.to_string(),
            p.label.to_string(),
            p.normal[0].to_string(),
            p.normal[1].to_string(),
            p.normal[2].to_string(),
            "0".into(),
            "0".into(),
            "0".into(),
            p.time.to_string(),
            p.ring.to_string(),
        ];
        out.push_str(&vals.join(sep));
        out.push_str(if i % 3 == 0 { "\r\n" } else { "\n" });
    }
    out.into_bytes()
}

fn check(cloud: &PcdCloud, pts: &[P]) {
    assert_eq!(cloud.len(), pts.len());
    assert_eq!(cloud.header.points, pts.len());
    assert_eq!(cloud.header.viewpoint, [1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0]);
    let rgb = cloud.rgb.as_ref().expect("rgb");
    let intensity = cloud.intensity.as_ref().expect("intensity");
    let label = cloud.label.as_ref().expect("label");
    for (i, p) in pts.iter().enumerate() {
        let want = p.xyz.map(f64::from);
        assert_eq!(cloud.xyz[i], want, "point {i}");
        let c = p.rgba;
        assert_eq!(
            rgb[i],
            [(c >> 16) as u8, (c >> 8) as u8, c as u8],
            "point {i}"
        );
        assert_eq!(intensity[i], p.intensity, "point {i}");
        assert_eq!(label[i], p.label, "point {i}");
    }
    assert_eq!(cloud.other_fields, vec!["normal", "gps_time", "ring"]);
}

#[test]
fn all_three_modes_decode_the_same_values() {
    let pts = points(300);
    let b = parse_pcd(&binary(&pts)).expect("binary");
    let c = parse_pcd(&compressed(&pts)).expect("binary_compressed");
    let a = parse_pcd(&ascii(&pts)).expect("ascii");
    check(&b, &pts);
    check(&c, &pts);
    check(&a, &pts);
    assert_eq!(b.header.data, DataMode::Binary);
    assert_eq!(c.header.data, DataMode::BinaryCompressed);
    assert_eq!(a.header.data, DataMode::Ascii);
    assert_eq!(
        (b.xyz.clone(), b.rgb.clone()),
        (c.xyz.clone(), c.rgb.clone())
    );
}

#[test]
fn compressed_fixture_uses_back_references() {
    // The fixture must exercise both run kinds of the decoder.
    let pts = points(300);
    let bytes = compressed(&pts);
    let raw: usize = 300 * (4 * 6 + 12 + 3 + 8 + 2);
    let at = header(300, "binary_compressed").len();
    let packed = u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    assert!((packed as usize) < raw * 9 / 10, "{packed} of {raw}");
}

#[test]
fn organised_cloud_with_nan_points() {
    let (w, h) = (4usize, 3usize);
    let mut body = Vec::new();
    for i in 0..w * h {
        let p: [f32; 3] = if i % 5 == 2 {
            [f32::NAN; 3]
        } else {
            [i as f32, 2.0 * i as f32, 1.0]
        };
        let rgb = f32::from_bits(0x0011_2233 + i as u32);
        for v in [p[0], p[1], p[2], rgb] {
            body.extend(v.to_le_bytes());
        }
    }
    let packed = lzf::compress(&{
        // field-major
        let mut fm = Vec::new();
        for f in 0..4 {
            for i in 0..w * h {
                fm.extend_from_slice(&body[16 * i + 4 * f..16 * i + 4 * f + 4]);
            }
        }
        fm
    });
    let mut file = format!(
        "VERSION .7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH {w}\n\
         HEIGHT {h}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {}\nDATA binary_compressed\n",
        w * h
    )
    .into_bytes();
    file.extend((packed.len() as u32).to_le_bytes());
    file.extend((body.len() as u32).to_le_bytes());
    file.extend(&packed);
    let mut cloud = parse_pcd(&file).expect("pcd");
    assert_eq!((cloud.header.width, cloud.header.height), (w, h));
    assert_eq!(cloud.len(), 12);
    assert_eq!(cloud.finite_count(), 10);
    assert_eq!(cloud.rgb.as_ref().expect("rgb")[7], [0x11, 0x22, 0x33 + 7]);
    assert_eq!(cloud.xyz[11], [11.0, 22.0, 1.0]);
    cloud.retain_finite();
    assert_eq!(cloud.len(), 10);
    assert_eq!(cloud.rgb.as_ref().map(Vec::len), Some(10));
    assert_eq!(cloud.xyz[2], [3.0, 6.0, 1.0]);
    assert_eq!((cloud.header.width, cloud.header.height), (10, 1));
}

#[test]
fn old_versions_and_optional_lines() {
    // v0.6-style: no VIEWPOINT, no COUNT, no HEIGHT; and a file with no VERSION at all.
    let text = "VERSION .6\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nPOINTS 2\nDATA ascii\n\
                1 2 3\n4 5 6\n";
    let c = parse_pcd(text.as_bytes()).expect("v0.6");
    assert_eq!(c.xyz, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    assert_eq!(c.header.version.as_deref(), Some(".6"));
    let text = "FIELDS x y z label\nSIZE 8 8 8 4\nTYPE F F F I\nPOINTS 1\nDATA ascii\n\
                0.1 -0.2 3e2 17\n";
    let c = parse_pcd(text.as_bytes()).expect("no version");
    assert_eq!(c.xyz, vec![[0.1, -0.2, 300.0]]);
    assert_eq!(c.label, Some(vec![17]));
    assert_eq!(c.header.version, None);
    assert!(c.rgb.is_none() && c.intensity.is_none() && c.other_fields.is_empty());
}

fn err(bytes: &[u8]) -> PcdError {
    match parse_pcd(bytes) {
        Ok(_) => panic!("expected an error"),
        Err(e) => e,
    }
}

const XYZ: &str = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n";

#[test]
fn errors_name_the_problem() {
    let e = err(format!("{XYZ}WIDTH 2\nPOINTS 2\nDATA binary\n").as_bytes());
    assert!(
        matches!(
            e,
            PcdError::Truncated {
                expected: 24,
                found: 0,
                ..
            }
        ),
        "{e}"
    );
    let e = err(format!("{XYZ}WIDTH 2\nPOINTS 2\nDATA ascii\n1 2 3\n").as_bytes());
    assert!(
        matches!(
            e,
            PcdError::Truncated {
                expected: 2,
                found: 1,
                ..
            }
        ),
        "{e}"
    );
    let e = err(format!("{XYZ}POINTS 1\nDATA ascii\n1 2\n").as_bytes());
    assert!(
        matches!(
            e,
            PcdError::BadValueCount {
                line_no: 7,
                expected: 3,
                found: 2
            }
        ),
        "{e}"
    );
    let e = err(format!("{XYZ}POINTS 1\nDATA ascii\n1 2 abc\n").as_bytes());
    assert!(e.to_string().contains("\"abc\" of field \"z\""), "{e}");
    let e = err(b"FIELDS x y z\nSIZE 4 4 2\nTYPE F F F\nPOINTS 1\nDATA binary\n");
    assert!(
        matches!(
            e,
            PcdError::UnsupportedType {
                size: 2,
                ty: 'F',
                ..
            }
        ),
        "{e}"
    );
    let e = err(b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F Q\nPOINTS 1\nDATA binary\n");
    assert!(
        matches!(e, PcdError::BadHeaderLine { line_no: 3, .. }),
        "{e}"
    );
    let e = err(format!("{XYZ}FOO 1\nPOINTS 1\nDATA binary\n").as_bytes());
    assert!(e.to_string().contains("unknown keyword \"FOO\""), "{e}");
    let e = err(format!("{XYZ}POINTS 1\nDATA binary_packed\n").as_bytes());
    assert!(matches!(e, PcdError::UnsupportedDataMode(_)), "{e}");
    let e = err(format!("{XYZ}POINTS 1\n").as_bytes());
    assert!(matches!(e, PcdError::MissingHeader("DATA")), "{e}");
    let e = err(format!("{XYZ}WIDTH 3\nHEIGHT 2\nPOINTS 5\nDATA ascii\n").as_bytes());
    assert!(matches!(e, PcdError::Inconsistent(_)), "{e}");
    let e = err(b"FIELDS x y\nSIZE 4 4 4\nTYPE F F F\nPOINTS 0\nDATA ascii\n");
    assert!(e.to_string().contains("SIZE has 3 entries"), "{e}");
    let e = err(b"FIELDS x y w\nSIZE 4 4 4\nTYPE F F F\nPOINTS 0\nDATA ascii\n");
    assert!(matches!(e, PcdError::MissingField("z")), "{e}");
    let e =
        err(b"FIELDS x y z label\nSIZE 4 4 4 4\nTYPE F F F F\nPOINTS 1\nDATA ascii\n0 0 0 1.5\n");
    assert!(matches!(e, PcdError::BadLabel { point: 0, .. }), "{e}");
    let e = err(b"FIELDS x y z rgb\nSIZE 4 4 4 2\nTYPE F F F U\nPOINTS 0\nDATA ascii\n");
    assert!(matches!(e, PcdError::UnsupportedType { .. }), "{e}");
    let e =
        err(b"FIELDS x y z ring\nSIZE 4 4 4 1\nTYPE F F F I\nPOINTS 1\nDATA ascii\n0 0 0 200\n");
    assert!(matches!(e, PcdError::BadValue { .. }), "{e}");
}

#[test]
fn compressed_errors() {
    let head = format!("{XYZ}POINTS 2\nDATA binary_compressed\n").into_bytes();
    // Size header cut short.
    let mut f = head.clone();
    f.extend([1, 0, 0]);
    assert!(matches!(err(&f), PcdError::Truncated { expected: 8, .. }));
    // Announced size disagrees with POINTS × 12.
    let mut f = head.clone();
    f.extend(4u32.to_le_bytes());
    f.extend(23u32.to_le_bytes());
    assert!(matches!(err(&f), PcdError::Inconsistent(_)));
    // Stream shorter than announced.
    let mut f = head.clone();
    f.extend(40u32.to_le_bytes());
    f.extend(24u32.to_le_bytes());
    f.extend([0u8; 10]);
    assert!(matches!(
        err(&f),
        PcdError::Truncated {
            expected: 40,
            found: 10,
            ..
        }
    ));
    // Corrupt stream: a back-reference into nothing.
    let mut f = head;
    f.extend(2u32.to_le_bytes());
    f.extend(24u32.to_le_bytes());
    f.extend([0x20, 0x05]);
    assert!(matches!(
        err(&f),
        PcdError::Lzf(lzf::LzfError::BadReference { .. })
    ));
}

#[test]
fn read_pcd_names_the_file() {
    let e = read_pcd(Path::new("/nonexistent/cloud.pcd")).expect_err("missing file");
    assert!(e.to_string().contains("/nonexistent/cloud.pcd"), "{e}");
    let dir = std::env::temp_dir().join(format!("segeval-pcd-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp dir");
    let path = dir.join("bad.pcd");
    std::fs::write(
        &path,
        b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 3\nDATA binary\n",
    )
    .expect("write");
    let e = read_pcd(&path).expect_err("truncated");
    assert!(
        e.to_string().contains("bad.pcd") && e.to_string().contains("truncated"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Fuzzing regression (issue 23, `pcd` target): an ASCII body of one line under a header of
/// 9311 × 9311 points reserved the header's count up front (4.5 GB, out of memory). The
/// reservation is bounded by the body now and the short body is an error.
#[test]
fn ascii_count_beyond_the_body_is_an_error_not_a_huge_reservation() {
    let pcd = b"# .N\r\nFIELDS x y z\r\nSIZE 4 4 4\r\nTYPE F F F\r\nCOUNT 11 1 1\r\nWIDTH 9311\r\nHEIGHT  9311\r\nDATA ascii\r\n44.250        -18.1    5.850\r\n 0";
    assert!(parse_pcd(pcd).is_err());
}
