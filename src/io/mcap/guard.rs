//! Length prefixes of MCAP records checked before the `mcap` crate parses them.
//!
//! The crate allocates a string, byte array or map by the length its prefix states before it
//! reads the bytes, so one corrupt prefix in a record makes it ask for up to 4 GiB (and the
//! process aborts). Every variable-length field of a record must fit inside the record: that
//! is checked here, from the field layout of each record type in the MCAP specification.

/// One field of a record, in order.
#[derive(Clone, Copy)]
enum F {
    /// Fixed size, bytes.
    Fixed(usize),
    /// `u32` byte length + UTF-8 bytes.
    Str,
    /// `u32` byte length + bytes (also maps and arrays, whose prefix counts bytes).
    Bytes32,
    /// `u64` byte length + bytes.
    Bytes64,
    /// Everything to the end of the record.
    Rest,
}

fn layout(opcode: u8) -> Option<&'static [F]> {
    use F::*;
    Some(match opcode {
        0x01 => &[Str, Str],                                     // header
        0x02 => &[Fixed(20)],                                    // footer
        0x03 => &[Fixed(2), Str, Str, Bytes32],                  // schema
        0x04 => &[Fixed(4), Str, Str, Bytes32],                  // channel (+ metadata map)
        0x05 => &[Fixed(22), Rest],                              // message
        0x06 => &[Fixed(28), Str, Bytes64],                      // chunk
        0x07 => &[Fixed(2), Bytes32],                            // message index
        0x08 => &[Fixed(32), Bytes32, Fixed(8), Str, Fixed(16)], // chunk index
        0x09 => &[Fixed(16), Str, Str, Bytes64, Fixed(4)],       // attachment
        0x0A => &[Fixed(40), Str, Str],                          // attachment index
        0x0B => &[Fixed(42), Bytes32],                           // statistics
        0x0C => &[Str, Bytes32],                                 // metadata
        0x0D => &[Fixed(16), Str],                               // metadata index
        0x0E => &[Fixed(17)],                                    // summary offset
        0x0F => &[Fixed(4)],                                     // data end
        _ => return None,
    })
}

/// Checks that every variable-length field of a record of `opcode` with body `data` fits
/// in the body. Unknown opcodes pass (the crate keeps them as opaque bytes).
pub fn check_record(opcode: u8, data: &[u8]) -> Result<(), String> {
    let Some(fields) = layout(opcode) else {
        return Ok(());
    };
    let mut at = 0usize;
    let short = |at: usize, need: u64| {
        format!(
            "record 0x{opcode:02x} of {} bytes: a field at byte {at} needs {need} bytes",
            data.len()
        )
    };
    for f in fields {
        let left = data.len() - at;
        let (prefix, len) = match f {
            F::Fixed(n) => (0, *n as u64),
            F::Rest => return Ok(()),
            F::Str | F::Bytes32 => {
                if left < 4 {
                    return Err(short(at, 4));
                }
                let b = &data[at..at + 4];
                (4, u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])))
            }
            F::Bytes64 => {
                if left < 8 {
                    return Err(short(at, 8));
                }
                let b: [u8; 8] = data[at..at + 8].try_into().unwrap_or([0xff; 8]);
                (8, u64::from_le_bytes(b))
            }
        };
        let need = len.saturating_add(prefix);
        if need > left as u64 {
            return Err(short(at, need));
        }
        at += need as usize;
    }
    Ok(())
}

/// Checks the records of `bytes` (a sequence of records: opcode, `u64` length, body) up to
/// its end; the first record that does not fit or fails [`check_record`] is the error.
pub fn check_records(bytes: &[u8]) -> Result<(), String> {
    let mut at = 0usize;
    while at < bytes.len() {
        if bytes.len() - at < 9 {
            return Err(format!("record at byte {at} is cut off"));
        }
        let op = bytes[at];
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap_or([0xff; 8]));
        let body = at + 9;
        if len > (bytes.len() - body) as u64 {
            return Err(format!(
                "record 0x{op:02x} at byte {at} claims {len} bytes, past the end"
            ));
        }
        check_record(op, &bytes[body..body + len as usize])
            .map_err(|e| format!("at byte {at}: {e}"))?;
        at = body + len as usize;
    }
    Ok(())
}

/// Checks the first record of `bytes` (opcode, `u64` length, body).
pub fn check_first_record(bytes: &[u8]) -> Result<(), String> {
    if bytes.len() < 9 {
        return Err("cut off".into());
    }
    let len = u64::from_le_bytes(bytes[1..9].try_into().unwrap_or([0xff; 8]));
    if len > (bytes.len() - 9) as u64 {
        return Err(format!("it claims {len} bytes, past the end of the file"));
    }
    check_record(bytes[0], &bytes[9..9 + len as usize])
}

/// Checks the summary section of the MCAP file `map` (from the footer's summary start to the
/// footer) before the crate reads it. A file without a footer or summary passes.
pub fn check_summary(map: &[u8]) -> Result<(), String> {
    // The footer record (opcode, length, 20-byte body) sits before the closing magic.
    let magic = mcap::MAGIC.len();
    if map.len() < 2 * magic + 29 {
        return Ok(());
    }
    let footer = map.len() - magic - 29;
    if map[footer] != 0x02 {
        return Ok(());
    }
    let body = &map[footer + 9..footer + 29];
    let start = u64::from_le_bytes(body[..8].try_into().unwrap_or([0; 8]));
    if start == 0 {
        return Ok(());
    }
    if start < magic as u64 || start > footer as u64 {
        return Err(format!(
            "the footer places the summary at byte {start}, outside the file's records"
        ));
    }
    check_records(&map[start as usize..footer]).map_err(|e| format!("summary: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn string(s: &str) -> Vec<u8> {
        let mut v = (s.len() as u32).to_le_bytes().to_vec();
        v.extend(s.as_bytes());
        v
    }

    #[test]
    fn lengths_past_the_record_are_refused() {
        let mut header = string("ros2");
        header.extend(string("tessera"));
        check_record(0x01, &header).unwrap();
        let mut bad = header.clone();
        bad[..4].copy_from_slice(&0xfffe_fffcu32.to_le_bytes());
        assert!(check_record(0x01, &bad)
            .unwrap_err()
            .contains("needs 4294901760"));
        assert!(check_record(0x01, &header[..6]).is_err());
        // A message's data runs to the end of the record; a short one is refused.
        check_record(0x05, &[0u8; 22]).unwrap();
        assert!(check_record(0x05, &[0u8; 21]).is_err());
        // Unknown opcodes pass.
        check_record(0x80, &[1, 2, 3]).unwrap();
        // A chunk whose records length overruns.
        let mut chunk = vec![0u8; 28];
        chunk.extend(string("lz4"));
        chunk.extend(u64::MAX.to_le_bytes());
        assert!(check_record(0x06, &chunk).is_err());
    }

    #[test]
    fn record_sequences_are_walked() {
        let mut rec = vec![0x0F];
        rec.extend(4u64.to_le_bytes());
        rec.extend([0u8; 4]);
        let mut two = rec.clone();
        two.extend(&rec);
        check_records(&two).unwrap();
        two.truncate(two.len() - 1);
        assert!(check_records(&two).unwrap_err().contains("past the end"));
    }
}
