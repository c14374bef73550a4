//! Wire formats of ROS messages inside MCAP: ROS 1 serialisation (`ros1` message encoding:
//! little-endian, packed, `u32` string/array lengths) and ROS 2 CDR (`cdr`: a 4-byte
//! encapsulation header selecting the byte order, then every primitive aligned to its size
//! relative to the end of that header, strings carrying their NUL terminator).
//!
//! One reader serves both so the message decoders are written once; the differences live in
//! alignment, [`WireReader::string`] and [`WireReader::time`].

use std::fmt;

/// Why a message could not be decoded (the caller adds file, topic and time).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DecodeError(pub String);

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for DecodeError {}

/// Result of message decoding.
pub type DResult<T> = std::result::Result<T, DecodeError>;

/// The message encodings tessera reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// ROS 1 serialisation (`message_encoding = "ros1"`).
    Ros1,
    /// ROS 2 CDR (`message_encoding = "cdr"`).
    Cdr,
}

impl Encoding {
    /// The encoding for an MCAP channel's `message_encoding`, `None` if unsupported.
    pub fn from_channel(message_encoding: &str) -> Option<Encoding> {
        match message_encoding {
            "ros1" => Some(Encoding::Ros1),
            "cdr" => Some(Encoding::Cdr),
            _ => None,
        }
    }
}

/// A ROS time stamp: seconds and nanoseconds since the Unix epoch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default)]
pub struct Stamp {
    /// Seconds (signed in ROS 2).
    pub sec: i64,
    /// Nanoseconds, 0..1e9.
    pub nsec: u32,
}

impl Stamp {
    /// Nanoseconds since the epoch.
    pub fn as_nanos(&self) -> i128 {
        self.sec as i128 * 1_000_000_000 + self.nsec as i128
    }
    /// Seconds since the epoch as f64 (≈ 0.2 µs resolution for current dates).
    pub fn as_secs_f64(&self) -> f64 {
        self.sec as f64 + self.nsec as f64 * 1e-9
    }
    /// A stamp from nanoseconds since the epoch.
    pub fn from_nanos(ns: i128) -> Stamp {
        Stamp {
            sec: ns.div_euclid(1_000_000_000) as i64,
            nsec: ns.rem_euclid(1_000_000_000) as u32,
        }
    }
}

impl fmt::Display for Stamp {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{:09} s", self.sec, self.nsec)
    }
}

/// A cursor over one serialised message.
#[derive(Debug, Clone)]
pub struct WireReader<'a> {
    buf: &'a [u8],
    pos: usize,
    /// CDR alignment origin (the end of the encapsulation header); 0 for ROS 1.
    origin: usize,
    big_endian: bool,
    encoding: Encoding,
}

impl<'a> WireReader<'a> {
    /// Starts reading `buf` in `encoding`. For CDR the encapsulation header is checked here:
    /// `00 00` (big-endian) and `00 01` (little-endian) plain CDR are supported.
    pub fn new(buf: &'a [u8], encoding: Encoding) -> DResult<Self> {
        match encoding {
            Encoding::Ros1 => Ok(WireReader {
                buf,
                pos: 0,
                origin: 0,
                big_endian: false,
                encoding,
            }),
            Encoding::Cdr => {
                let head = buf.get(..4).ok_or_else(|| {
                    DecodeError(format!(
                        "CDR message of {} bytes is shorter than its 4-byte encapsulation header",
                        buf.len()
                    ))
                })?;
                let big_endian = match (head[0], head[1]) {
                    (0, 0) => true,
                    (0, 1) => false,
                    (a, b) => {
                        return Err(DecodeError(format!(
                            "unsupported CDR encapsulation kind {a:#04x} {b:#04x} (plain CDR_BE 00 00 and CDR_LE 00 01 are supported)"
                        )))
                    }
                };
                Ok(WireReader {
                    buf,
                    pos: 4,
                    origin: 4,
                    big_endian,
                    encoding,
                })
            }
        }
    }

    /// Whether multi-byte values are big-endian (CDR_BE).
    pub fn big_endian(&self) -> bool {
        self.big_endian
    }

    /// Current offset in the message.
    pub fn position(&self) -> usize {
        self.pos
    }

    fn align(&mut self, n: usize) -> DResult<()> {
        if self.encoding == Encoding::Cdr && n > 1 {
            let rel = self.pos - self.origin;
            let pad = (n - rel % n) % n;
            if self.pos + pad > self.buf.len() {
                return Err(self.eof(pad));
            }
            self.pos += pad;
        }
        Ok(())
    }

    fn eof(&self, need: usize) -> DecodeError {
        DecodeError(format!(
            "message ends at byte {} but {need} more bytes are needed at offset {} (truncated or not the schema it claims)",
            self.buf.len(),
            self.pos
        ))
    }

    /// The next `n` raw bytes (no alignment).
    pub fn bytes(&mut self, n: usize) -> DResult<&'a [u8]> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.buf.len());
        match end {
            Some(end) => {
                let s = &self.buf[self.pos..end];
                self.pos = end;
                Ok(s)
            }
            None => Err(self.eof(n)),
        }
    }

    fn fixed<const N: usize>(&mut self) -> DResult<[u8; N]> {
        self.align(N)?;
        let b = self.bytes(N)?;
        let mut a = [0u8; N];
        a.copy_from_slice(b);
        if self.big_endian {
            a.reverse();
        }
        Ok(a)
    }

    /// A `uint8`.
    pub fn u8(&mut self) -> DResult<u8> {
        Ok(self.bytes(1)?[0])
    }
    /// A `bool` (any non-zero byte is true).
    pub fn bool(&mut self) -> DResult<bool> {
        Ok(self.u8()? != 0)
    }
    /// A `uint32`.
    pub fn u32(&mut self) -> DResult<u32> {
        Ok(u32::from_le_bytes(self.fixed()?))
    }
    /// An `int32`.
    pub fn i32(&mut self) -> DResult<i32> {
        Ok(i32::from_le_bytes(self.fixed()?))
    }
    /// A `float64`.
    pub fn f64(&mut self) -> DResult<f64> {
        Ok(f64::from_le_bytes(self.fixed()?))
    }

    /// A `string`.
    pub fn string(&mut self) -> DResult<&'a str> {
        let n = self.u32()? as usize;
        let raw = self.bytes(n)?;
        let s = match self.encoding {
            // CDR strings count and carry their NUL terminator.
            Encoding::Cdr => match raw.split_last() {
                Some((0, s)) => s,
                Some(_) => {
                    return Err(DecodeError(format!(
                        "CDR string of {n} bytes at offset {} lacks its NUL terminator",
                        self.pos - n
                    )))
                }
                None => raw,
            },
            Encoding::Ros1 => raw,
        };
        std::str::from_utf8(s)
            .map_err(|e| DecodeError(format!("string at offset {}: {e}", self.pos - n)))
    }

    /// The element count of a sequence (`T[]`), checked against the bytes left assuming each
    /// element takes at least `min_elem_bytes`, so a corrupt count cannot trigger a huge
    /// allocation.
    pub fn seq_len(&mut self, min_elem_bytes: usize) -> DResult<usize> {
        let n = self.u32()? as usize;
        let left = self.buf.len() - self.pos;
        if n.saturating_mul(min_elem_bytes.max(1)) > left {
            return Err(DecodeError(format!(
                "sequence of {n} elements at offset {} cannot fit in the {left} bytes left",
                self.pos
            )));
        }
        Ok(n)
    }

    /// A `time` (ROS 1: `u32` sec, `u32` nsec) or `builtin_interfaces/Time` (ROS 2: `i32` sec,
    /// `u32` nanosec).
    pub fn time(&mut self) -> DResult<Stamp> {
        let sec = match self.encoding {
            Encoding::Ros1 => self.u32()? as i64,
            Encoding::Cdr => self.i32()? as i64,
        };
        let nsec = self.u32()?;
        if nsec >= 1_000_000_000 {
            return Err(DecodeError(format!(
                "time stamp with {nsec} nanoseconds (must be < 1e9)"
            )));
        }
        Ok(Stamp { sec, nsec })
    }

    /// A `std_msgs/Header`: ROS 1 has a leading `seq`, ROS 2 does not.
    pub fn header(&mut self) -> DResult<(Stamp, &'a str)> {
        if self.encoding == Encoding::Ros1 {
            self.u32()?; // seq
        }
        let stamp = self.time()?;
        let frame = self.string()?;
        Ok((stamp, frame))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cdr_aligns_relative_to_the_encapsulation_header() {
        // CDR_LE: u8 at 0, then f64 aligned to 8 (relative offset 8), then u32 at 16.
        let mut b = vec![0, 1, 0, 0, 7];
        b.extend([0u8; 7]);
        b.extend(2.5f64.to_le_bytes());
        b.extend(9u32.to_le_bytes());
        let mut r = WireReader::new(&b, Encoding::Cdr).unwrap();
        assert_eq!(r.u8().unwrap(), 7);
        assert_eq!(r.f64().unwrap(), 2.5);
        assert_eq!(r.u32().unwrap(), 9);
        assert!(r.u8().is_err());
    }

    #[test]
    fn cdr_big_endian_and_strings() {
        let mut b = vec![0, 0, 0, 0];
        b.extend(4u32.to_be_bytes());
        b.extend(b"map\0");
        b.extend((-3i32).to_be_bytes());
        let mut r = WireReader::new(&b, Encoding::Cdr).unwrap();
        assert!(r.big_endian());
        assert_eq!(r.string().unwrap(), "map");
        assert_eq!(r.i32().unwrap(), -3);
    }

    #[test]
    fn ros1_is_packed_and_strings_have_no_terminator() {
        let mut b = vec![];
        b.extend(11u32.to_le_bytes()); // seq
        b.extend(5u32.to_le_bytes());
        b.extend(6u32.to_le_bytes());
        b.extend(3u32.to_le_bytes());
        b.extend(b"map");
        b.push(1);
        b.extend(1.5f64.to_le_bytes());
        let mut r = WireReader::new(&b, Encoding::Ros1).unwrap();
        let (t, f) = r.header().unwrap();
        assert_eq!((t.sec, t.nsec, f), (5, 6, "map"));
        assert_eq!(r.u8().unwrap(), 1);
        assert_eq!(r.f64().unwrap(), 1.5);
    }

    #[test]
    fn corrupt_lengths_are_errors_not_allocations() {
        let mut b = vec![0, 1, 0, 0];
        b.extend(u32::MAX.to_le_bytes());
        let mut r = WireReader::new(&b, Encoding::Cdr).unwrap();
        assert!(r.seq_len(1).is_err());
        let mut r = WireReader::new(&b, Encoding::Cdr).unwrap();
        assert!(r.string().is_err());
        assert!(WireReader::new(&[0, 1], Encoding::Cdr).is_err());
        assert!(WireReader::new(&[0, 3, 0, 0], Encoding::Cdr).is_err());
    }

    #[test]
    fn stamps_round_trip_through_nanoseconds() {
        let s = Stamp {
            sec: -2,
            nsec: 250_000_000,
        };
        assert_eq!(Stamp::from_nanos(s.as_nanos()), s);
        assert_eq!(s.to_string(), "-2.250000000 s");
    }
}
