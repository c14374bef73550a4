//! LAS 1.4 extra-bytes attributes (R15 §2.16): 192-byte descriptors in the `LASF_Spec` /
//! record 4 VLR, laid out one after the other at the end of each point record.

/// `user_id` of the VLR holding the descriptors.
pub const USER_ID: &str = "LASF_Spec";
/// `record_id` of the VLR holding the descriptors.
pub const RECORD_ID: u16 = 4;
/// Descriptor size in bytes.
pub const DESCRIPTOR_LEN: usize = 192;
/// Data type code of an unsigned 32-bit attribute.
pub const TYPE_U32: u8 = 5;
/// Data type code of an unsigned 64-bit attribute.
pub const TYPE_U64: u8 = 7;

pub use crate::model::ExtraField;

/// A descriptor for a scalar attribute of `data_type` (1..=10).
pub fn descriptor(data_type: u8, name: &str, description: &str) -> Vec<u8> {
    let mut d = vec![0u8; DESCRIPTOR_LEN];
    d[2] = data_type;
    let name = &name.as_bytes()[..name.len().min(32)];
    d[4..4 + name.len()].copy_from_slice(name);
    let desc = &description.as_bytes()[..description.len().min(32)];
    d[160..160 + desc.len()].copy_from_slice(desc);
    d
}

/// Size in bytes of a data type; type 0 takes its size from the `options` byte.
fn type_size(data_type: u8, options: u8) -> usize {
    let scalar = |t: u8| match t {
        1 | 2 => 1,
        3 | 4 => 2,
        5 | 6 | 9 => 4,
        7 | 8 | 10 => 8,
        _ => 0,
    };
    match data_type {
        0 => usize::from(options),
        1..=10 => scalar(data_type),
        11..=20 => 2 * scalar(data_type - 10),
        21..=30 => 3 * scalar(data_type - 20),
        _ => 0,
    }
}

/// The attributes described by an extra-bytes VLR's data, with their offsets.
pub fn fields(vlr_data: &[u8]) -> Vec<ExtraField> {
    let mut offset = 0;
    vlr_data
        .chunks_exact(DESCRIPTOR_LEN)
        .map(|d| {
            let name_bytes = &d[4..36];
            let end = name_bytes.iter().position(|&b| b == 0).unwrap_or(32);
            let f = ExtraField {
                name: String::from_utf8_lossy(&name_bytes[..end]).into_owned(),
                data_type: d[2],
                offset,
                size: type_size(d[2], d[3]),
            };
            offset += f.size;
            f
        })
        .collect()
}

/// Checks an extra-bytes VLR against the records it describes (`extra_bytes` per record)
/// before its bytes are carried into outputs: whole descriptors, known data types (0 with a
/// size, 1–10, and the deprecated 2- and 3-element arrays 11–30), non-empty unique names, and
/// descriptors that fit the record. Descriptors covering fewer bytes than the record are
/// allowed (the rest is undocumented, which readers keep as raw bytes); covering more is not.
/// Measured with laspy 2.7: unknown types, a zero size, duplicate names and oversized
/// descriptors make its reader raise, empty names make the field unreadable.
pub fn validate(vlr_data: &[u8], extra_bytes: u16) -> Result<Vec<ExtraField>, String> {
    if !vlr_data.len().is_multiple_of(DESCRIPTOR_LEN) {
        return Err(format!(
            "the extra-bytes VLR is {} bytes, not a whole number of {DESCRIPTOR_LEN}-byte descriptors",
            vlr_data.len()
        ));
    }
    let f = fields(vlr_data);
    let mut seen = std::collections::HashSet::new();
    for (i, (d, x)) in vlr_data.chunks_exact(DESCRIPTOR_LEN).zip(&f).enumerate() {
        let what = format!("extra-bytes descriptor {i} (\"{}\")", x.name);
        if d[2] > 30 {
            return Err(format!("{what}: unknown data type {}", d[2]));
        }
        if x.size == 0 {
            return Err(format!("{what}: data type 0 with a size of 0 bytes"));
        }
        if x.name.is_empty() {
            return Err(format!("{what}: empty name"));
        }
        if !seen.insert(x.name.as_str()) {
            return Err(format!("{what}: the name appears twice"));
        }
    }
    let total: usize = f.iter().map(|x| x.size).sum();
    if total > usize::from(extra_bytes) {
        return Err(format!(
            "the extra-bytes descriptors cover {total} bytes but the point records have {extra_bytes} extra bytes"
        ));
    }
    Ok(f)
}

#[cfg(test)]
mod tests {

    #[test]
    fn validate_rejects_what_readers_cannot_read() {
        let mut ok = descriptor(3, "a", "");
        ok.extend(descriptor(10, "b", ""));
        assert_eq!(validate(&ok, 10).unwrap().len(), 2);
        assert!(
            validate(&ok, 12).is_ok(),
            "undocumented trailing bytes are allowed"
        );
        assert!(validate(&ok, 9).unwrap_err().contains("cover 10 bytes"));
        assert!(validate(&ok[..300], 10)
            .unwrap_err()
            .contains("whole number"));
        let mut t = ok.clone();
        t[2] = 31;
        assert!(validate(&t, 10)
            .unwrap_err()
            .contains("unknown data type 31"));
        t[2] = 0;
        assert!(validate(&t, 10).unwrap_err().contains("size of 0"));
        let mut dup = descriptor(3, "a", "");
        dup.extend(descriptor(10, "a", ""));
        assert!(validate(&dup, 10).unwrap_err().contains("twice"));
        let empty = descriptor(3, "", "");
        assert!(validate(&empty, 2).unwrap_err().contains("empty name"));
        let arr = descriptor(13, "pair", "");
        assert_eq!(validate(&arr, 4).unwrap()[0].size, 4);
    }
    use super::*;

    #[test]
    fn offsets_follow_the_descriptor_sizes() {
        let mut data = descriptor(1, "gt_class", "");
        data.extend(descriptor(TYPE_U32, "gt_segment", ""));
        let mut opaque = descriptor(0, "blob", "");
        opaque[3] = 3;
        data.extend(opaque);
        data.extend(descriptor(10, "height", "metres"));
        let f = fields(&data);
        let got: Vec<(&str, usize, usize)> = f
            .iter()
            .map(|f| (f.name.as_str(), f.offset, f.size))
            .collect();
        assert_eq!(
            got,
            vec![
                ("gt_class", 0, 1),
                ("gt_segment", 1, 4),
                ("blob", 5, 3),
                ("height", 8, 8)
            ]
        );
    }
}
