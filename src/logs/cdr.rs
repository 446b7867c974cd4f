//! OMG CDR (XCDR1), the serialisation of ROS 2 messages, for the few message types aift writes
//! and reads (`messages.rs`). Written here rather than taken from a crate: the serde-based `cdr`
//! crate has had no release since 2021 and would still need the message structs and schemas by
//! hand; the encoding itself is a page (OMG DDS-XTypes 1.3, 7.4.3.5 "XCDR1"; ROS 2's
//! rmw_cyclonedds / Fast-CDR follow it): a 4-byte encapsulation header (0x00 0x01 = CDR, little
//! endian; 0x00 0x00 = big endian; two option bytes), then every primitive aligned to its size
//! counted from the end of the header; a string is a u32 length counting a NUL terminator, its
//! bytes and the NUL; a sequence a u32 count and its elements. tests/mcap_logs.rs and the Python
//! tests check the bytes against independent readers and writers (`mcap_ros2`, `rosbags`).

/// Little-endian CDR encapsulation.
const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// A CDR message being written (little endian).
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        Self::new()
    }
}

impl CdrWriter {
    pub fn new() -> Self {
        Self {
            buf: CDR_LE.to_vec(),
        }
    }

    /// Clears the buffer for the next message (keeping its allocation).
    pub fn reset(&mut self) {
        self.buf.clear();
        self.buf.extend_from_slice(&CDR_LE);
    }

    fn align(&mut self, n: usize) {
        let pos = self.buf.len() - 4;
        let pad = (n - pos % n) % n;
        self.buf.extend(std::iter::repeat_n(0u8, pad));
    }

    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    pub fn strings<S: AsRef<str>>(&mut self, v: &[S]) {
        self.u32(v.len() as u32);
        for s in v {
            self.string(s.as_ref());
        }
    }

    pub fn f64s(&mut self, v: &[f64]) {
        self.u32(v.len() as u32);
        for &x in v {
            self.f64(x);
        }
    }

    pub fn bytes(&self) -> &[u8] {
        &self.buf
    }
}

/// A CDR message being read (either byte order, from its encapsulation header).
pub struct CdrReader<'a> {
    data: &'a [u8],
    pos: usize,
    little: bool,
}

/// What went wrong reading a CDR message.
pub type CdrResult<T> = Result<T, String>;

impl<'a> CdrReader<'a> {
    pub fn new(data: &'a [u8]) -> CdrResult<Self> {
        let header: [u8; 4] = data
            .get(..4)
            .and_then(|h| h.try_into().ok())
            .ok_or_else(|| "shorter than a CDR header".to_string())?;
        let little = match header[..2] {
            [0x00, 0x01] => true,
            [0x00, 0x00] => false,
            _ => {
                return Err(format!(
                    "encapsulation {:02x}{:02x} is not plain CDR (0001 or 0000)",
                    header[0], header[1]
                ));
            }
        };
        Ok(Self {
            data: &data[4..],
            pos: 0,
            little,
        })
    }

    fn take(&mut self, n: usize, align: usize) -> CdrResult<&'a [u8]> {
        let start = self.pos.div_ceil(align) * align;
        let end = start
            .checked_add(n)
            .filter(|&e| e <= self.data.len())
            .ok_or_else(|| format!("ends at byte {} inside a field", self.data.len() + 4))?;
        self.pos = end;
        Ok(&self.data[start..end])
    }

    pub fn u8(&mut self) -> CdrResult<u8> {
        Ok(self.take(1, 1)?[0])
    }

    pub fn u32(&mut self) -> CdrResult<u32> {
        let b: [u8; 4] = self.take(4, 4)?.try_into().expect("4 bytes");
        Ok(if self.little {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        })
    }

    pub fn i32(&mut self) -> CdrResult<i32> {
        Ok(self.u32()? as i32)
    }

    pub fn f64(&mut self) -> CdrResult<f64> {
        let b: [u8; 8] = self.take(8, 8)?.try_into().expect("8 bytes");
        Ok(if self.little {
            f64::from_le_bytes(b)
        } else {
            f64::from_be_bytes(b)
        })
    }

    /// A count of elements of at least `min_size` bytes each, checked against what is left (so
    /// a corrupt count cannot ask for more memory than the message holds).
    fn count(&mut self, min_size: usize) -> CdrResult<usize> {
        let n = self.u32()? as usize;
        if n.saturating_mul(min_size) > self.data.len() - self.pos {
            return Err(format!(
                "a sequence of {n} elements does not fit in the message"
            ));
        }
        Ok(n)
    }

    pub fn string(&mut self) -> CdrResult<String> {
        let n = self.count(1)?;
        let bytes = self.take(n, 1)?;
        let text = match bytes.split_last() {
            Some((0, s)) => s,
            _ => bytes,
        };
        String::from_utf8(text.to_vec()).map_err(|_| "a string is not UTF-8".to_string())
    }

    pub fn strings(&mut self) -> CdrResult<Vec<String>> {
        let n = self.count(4)?;
        (0..n).map(|_| self.string()).collect()
    }

    pub fn f64s(&mut self) -> CdrResult<Vec<f64>> {
        let n = self.count(8)?;
        (0..n).map(|_| self.f64()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Big-endian CDR encapsulation.
    const CDR_BE: [u8; 4] = [0x00, 0x00, 0x00, 0x00];

    #[test]
    fn alignment_counts_from_the_end_of_the_header() {
        let mut w = CdrWriter::new();
        w.u8(7);
        w.f64(1.5);
        w.string("ab");
        w.f64s(&[2.0]);
        let b = w.bytes();
        // header, u8, 7 bytes of padding to offset 8, the f64, then u32 3 "ab\0", pad to 8.
        assert_eq!(&b[..5], &[0, 1, 0, 0, 7]);
        assert_eq!(&b[5..12], &[0; 7]);
        assert_eq!(&b[12..20], &1.5f64.to_le_bytes());
        assert_eq!(&b[20..27], &[3, 0, 0, 0, b'a', b'b', 0]);
        let mut r = CdrReader::new(b).unwrap();
        assert_eq!(r.u8().unwrap(), 7);
        assert_eq!(r.f64().unwrap(), 1.5);
        assert_eq!(r.string().unwrap(), "ab");
        assert_eq!(r.f64s().unwrap(), vec![2.0]);
    }

    #[test]
    fn big_endian_and_corrupt_counts() {
        let mut b = CDR_BE.to_vec();
        b.extend_from_slice(&2u32.to_be_bytes());
        b.extend_from_slice(&[0; 4]);
        b.extend_from_slice(&1.25f64.to_be_bytes());
        b.extend_from_slice(&(-3.0f64).to_be_bytes());
        assert_eq!(
            CdrReader::new(&b).unwrap().f64s().unwrap(),
            vec![1.25, -3.0]
        );
        let mut bad = CDR_LE.to_vec();
        bad.extend_from_slice(&u32::MAX.to_le_bytes());
        assert!(CdrReader::new(&bad).unwrap().f64s().is_err());
        assert!(CdrReader::new(&[0x00, 0x07, 0, 0]).is_err());
        assert!(CdrReader::new(&[0x00]).is_err());
    }
}
