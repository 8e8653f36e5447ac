//! A bounds-checked little-endian cursor over a file's bytes.
//!
//! Every read states what it reads; a read past the end is an error naming the byte offset and
//! the item (`truncated at byte 8817 while reading leaf buffer 3: needs 2048 bytes, 112 left`).
//! Nothing is allocated from a length in the file before the length has been checked against
//! the bytes left: slices of the input are returned, not copies.

/// A failed read: the field (section of the file) and a message naming the offset.
#[derive(Debug, Clone, PartialEq)]
pub struct Fail {
    pub field: String,
    pub msg: String,
}

impl Fail {
    pub fn new(field: &str, msg: impl Into<String>) -> Self {
        Self {
            field: field.to_string(),
            msg: msg.into(),
        }
    }

    /// Appends context to the message (e.g. which leaf was being read).
    pub fn context(mut self, what: impl std::fmt::Display) -> Self {
        self.msg = format!("{} ({what})", self.msg);
        self
    }
}

pub type PResult<T> = std::result::Result<T, Fail>;

/// Cursor over `bytes`; `field` labels the errors of the section being read.
pub struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
    pub field: &'static str,
}

impl<'a> Cursor<'a> {
    pub fn new(bytes: &'a [u8]) -> Self {
        Self {
            bytes,
            pos: 0,
            field: "header",
        }
    }

    pub fn pos(&self) -> usize {
        self.pos
    }

    pub fn left(&self) -> usize {
        self.bytes.len() - self.pos
    }

    pub fn len(&self) -> usize {
        self.bytes.len()
    }

    pub fn fail(&self, msg: impl Into<String>) -> Fail {
        Fail::new(self.field, msg)
    }

    /// Moves to an absolute offset read from the file (checked to lie inside it).
    pub fn seek(&mut self, to: i64, what: &str) -> PResult<()> {
        if to < 0 || to as u64 > self.bytes.len() as u64 {
            return Err(self.fail(format!(
                "{what} points to byte {to}, outside the file ({} bytes)",
                self.bytes.len()
            )));
        }
        self.pos = to as usize;
        Ok(())
    }

    /// The next `n` bytes.
    pub fn take(&mut self, n: usize, what: &str) -> PResult<&'a [u8]> {
        if n > self.left() {
            return Err(self.fail(format!(
                "truncated at byte {} while reading {what}: needs {n} bytes, {} left",
                self.pos,
                self.left()
            )));
        }
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    /// Like [`Self::take`] with a length read from the file as a signed 64-bit count.
    pub fn take_i64(&mut self, n: i64, what: &str) -> PResult<&'a [u8]> {
        if n < 0 || n as u64 > self.left() as u64 {
            return Err(self.fail(format!(
                "{what} at byte {} claims {n} bytes, {} are left",
                self.pos,
                self.left()
            )));
        }
        self.take(n as usize, what)
    }

    fn array<const N: usize>(&mut self, what: &str) -> PResult<[u8; N]> {
        let s = self.take(N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    pub fn u8(&mut self, what: &str) -> PResult<u8> {
        Ok(self.array::<1>(what)?[0])
    }

    pub fn u32(&mut self, what: &str) -> PResult<u32> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }

    pub fn i32(&mut self, what: &str) -> PResult<i32> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }

    pub fn i64(&mut self, what: &str) -> PResult<i64> {
        Ok(i64::from_le_bytes(self.array(what)?))
    }

    pub fn f32(&mut self, what: &str) -> PResult<f32> {
        Ok(f32::from_le_bytes(self.array(what)?))
    }

    pub fn f64(&mut self, what: &str) -> PResult<f64> {
        Ok(f64::from_le_bytes(self.array(what)?))
    }

    pub fn dvec3(&mut self, what: &str) -> PResult<[f64; 3]> {
        Ok([self.f64(what)?, self.f64(what)?, self.f64(what)?])
    }

    pub fn ivec3(&mut self, what: &str) -> PResult<[i32; 3]> {
        Ok([self.i32(what)?, self.i32(what)?, self.i32(what)?])
    }

    /// A length-prefixed (u32) byte string, as OpenVDB writes names and type names.
    pub fn string(&mut self, what: &str) -> PResult<String> {
        let n = self.u32(what)?;
        let s = self.take_i64(n as i64, what)?;
        Ok(String::from_utf8_lossy(s).into_owned())
    }

    /// A bit mask of `words` little-endian u64 words (OpenVDB `NodeMask::load`).
    pub fn mask(&mut self, words: usize, what: &str) -> PResult<Vec<u64>> {
        let s = self.take(words * 8, what)?;
        Ok(s.chunks_exact(8)
            .map(|c| u64::from_le_bytes(c.try_into().unwrap()))
            .collect())
    }
}

/// Bit `i` of a mask.
pub fn bit(mask: &[u64], i: usize) -> bool {
    mask[i / 64] >> (i % 64) & 1 == 1
}

/// Set bits of a mask.
pub fn count_on(mask: &[u64]) -> usize {
    mask.iter().map(|w| w.count_ones() as usize).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_are_bounded_and_name_the_offset() {
        let bytes = [1u8, 0, 0, 0, 5, 0, 0, 0, b'a'];
        let mut c = Cursor::new(&bytes);
        assert_eq!(c.u32("count").unwrap(), 1);
        let e = c.string("grid name").unwrap_err();
        assert_eq!(e.field, "header");
        assert!(
            e.msg.contains("at byte 8") && e.msg.contains("claims 5 bytes, 1 are left"),
            "{}",
            e.msg
        );
        let mut c = Cursor::new(&bytes);
        assert!(c.take_i64(-1, "x").is_err());
        assert!(c.take_i64(1 << 40, "x").is_err());
        assert!(c.seek(10, "end").is_err() && c.seek(9, "end").is_ok());
        let e = c.u8("leaf buffer").unwrap_err();
        assert!(
            e.msg
                .starts_with("truncated at byte 9 while reading leaf buffer")
        );
    }
}
