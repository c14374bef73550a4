//! LZF (Marc Lehmann's liblzf format), as used by PCD `binary_compressed`.
//!
//! The stream is a sequence of runs, each introduced by a control byte `c`:
//! - `c < 32`: a literal run of `c + 1` bytes follows;
//! - otherwise a back-reference: length `(c >> 5) + 2`, where a length code of 7 is extended by
//!   the next byte; distance `((c & 31) << 8) + next byte + 1` back from the end of the output.
//!   Source and destination may overlap (a run repeating a short pattern), so it is copied byte
//!   by byte.

/// Errors in an LZF stream; `at` is the input offset of the offending run.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LzfError {
    /// The input ends inside a run.
    #[error("LZF input ends inside the run at byte {at}")]
    Truncated {
        /// Input offset of the run.
        at: usize,
    },
    /// A back-reference points before the start of the output.
    #[error("LZF back-reference at byte {at} reaches {distance} bytes back but only {produced} were produced")]
    BadReference {
        /// Input offset of the run.
        at: usize,
        /// Distance of the reference.
        distance: usize,
        /// Bytes decompressed so far.
        produced: usize,
    },
    /// The output would exceed the announced size.
    #[error("LZF output exceeds the expected {expected} bytes at input byte {at}")]
    Overrun {
        /// Input offset of the run.
        at: usize,
        /// The announced size.
        expected: usize,
    },
    /// The input ended before producing the announced size.
    #[error("LZF output is {got} bytes, expected {expected}")]
    Short {
        /// Bytes produced.
        got: usize,
        /// The announced size.
        expected: usize,
    },
}

/// Decompresses `input`, which must expand to exactly `expected_len` bytes.
pub fn decompress(input: &[u8], expected_len: usize) -> Result<Vec<u8>, LzfError> {
    let mut out: Vec<u8> = Vec::with_capacity(expected_len);
    let mut i = 0usize;
    while i < input.len() {
        let at = i;
        let ctrl = usize::from(input[i]);
        i += 1;
        if ctrl < 32 {
            let len = ctrl + 1;
            let lit = input.get(i..i + len).ok_or(LzfError::Truncated { at })?;
            if out.len() + len > expected_len {
                return Err(LzfError::Overrun {
                    at,
                    expected: expected_len,
                });
            }
            out.extend_from_slice(lit);
            i += len;
        } else {
            let mut len = ctrl >> 5;
            if len == 7 {
                len += usize::from(*input.get(i).ok_or(LzfError::Truncated { at })?);
                i += 1;
            }
            let low = usize::from(*input.get(i).ok_or(LzfError::Truncated { at })?);
            i += 1;
            let distance = ((ctrl & 0x1f) << 8) + low + 1;
            let len = len + 2;
            if distance > out.len() {
                return Err(LzfError::BadReference {
                    at,
                    distance,
                    produced: out.len(),
                });
            }
            if out.len() + len > expected_len {
                return Err(LzfError::Overrun {
                    at,
                    expected: expected_len,
                });
            }
            let start = out.len() - distance;
            for k in 0..len {
                let b = out[start + k];
                out.push(b);
            }
        }
    }
    if out.len() != expected_len {
        return Err(LzfError::Short {
            got: out.len(),
            expected: expected_len,
        });
    }
    Ok(out)
}

const MAX_LITERAL: usize = 32;
const MAX_DISTANCE: usize = 1 << 13;
const MAX_MATCH: usize = 7 + 255 + 2;
const HASH_BITS: u32 = 14;

/// Compresses `input` into an LZF stream (greedy matching on 3-byte hashes). Used to write
/// `binary_compressed` data and to test the decoder; the output is valid for any LZF decoder.
pub fn compress(input: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(input.len() / 2 + 16);
    // Last position + 1 at which each 3-byte hash was seen (0 = never).
    let mut table = vec![0usize; 1 << HASH_BITS];
    let mut lit_start = 0usize;
    let mut i = 0usize;
    while i + 2 < input.len() {
        let h = hash3(&input[i..i + 3]);
        let cand = table[h];
        table[h] = i + 1;
        if cand > 0 {
            let j = cand - 1;
            let distance = i - j;
            if distance <= MAX_DISTANCE && input[j..j + 3] == input[i..i + 3] {
                let max = MAX_MATCH.min(input.len() - i);
                let mut len = 3;
                while len < max && input[j + len] == input[i + len] {
                    len += 1;
                }
                flush_literals(&mut out, &input[lit_start..i]);
                let code = len - 2;
                let d = distance - 1;
                if code < 7 {
                    out.push(((code << 5) | (d >> 8)) as u8);
                } else {
                    out.push(((7 << 5) | (d >> 8)) as u8);
                    out.push((code - 7) as u8);
                }
                out.push((d & 0xff) as u8);
                i += len;
                lit_start = i;
                continue;
            }
        }
        i += 1;
    }
    flush_literals(&mut out, &input[lit_start..]);
    out
}

fn hash3(b: &[u8]) -> usize {
    let v = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
    (v.wrapping_mul(2_654_435_761) >> (32 - HASH_BITS)) as usize
}

fn flush_literals(out: &mut Vec<u8>, lit: &[u8]) {
    for chunk in lit.chunks(MAX_LITERAL) {
        out.push((chunk.len() - 1) as u8);
        out.extend_from_slice(chunk);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_made_stream() {
        // "abc" literal, then a 6-byte back-reference at distance 3 (overlapping): "abcabcabc".
        let stream = [2u8, b'a', b'b', b'c', (4 << 5) as u8, 2];
        assert_eq!(decompress(&stream, 9).expect("lzf"), b"abcabcabc");
        // Long match with the extension byte: 'x' then 7+3+2 = 12 copies at distance 1.
        let stream = [0u8, b'x', 7 << 5, 3, 0];
        assert_eq!(decompress(&stream, 13).expect("lzf"), vec![b'x'; 13]);
    }

    #[test]
    fn corrupt_streams_are_errors() {
        assert_eq!(
            decompress(&[5, 1, 2], 6),
            Err(LzfError::Truncated { at: 0 })
        );
        assert!(matches!(
            decompress(&[0, 1, 1 << 5, 4], 10),
            Err(LzfError::BadReference { .. })
        ));
        assert!(matches!(
            decompress(&[2, 1, 2, 3], 2),
            Err(LzfError::Overrun { .. })
        ));
        assert_eq!(
            decompress(&[0, 1], 2),
            Err(LzfError::Short {
                got: 1,
                expected: 2
            })
        );
    }

    #[test]
    fn round_trip() {
        let mut data = Vec::new();
        let mut x = 12345u32;
        for k in 0..50_000u32 {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            // Mix of repetitive and random bytes, like float columns.
            data.push(if k % 3 == 0 {
                (x >> 24) as u8
            } else {
                (k / 100) as u8
            });
        }
        data.extend(std::iter::repeat_n(7u8, 5000));
        for input in [&data[..], &data[..1], &data[..2], &data[..3], &[][..]] {
            let c = compress(input);
            assert_eq!(decompress(&c, input.len()).expect("lzf"), input);
        }
        assert!(compress(&data).len() < data.len());
    }
}
