//! Binary PGM (P5) as netpbm defines it: a checked view, no allocation.
//!
//! Header: `P5`, whitespace, width, whitespace, height, whitespace, maxval,
//! exactly one whitespace byte, then `height` rows of `width` bytes. A `#`
//! comment runs to the end of the line and may appear anywhere before maxval's
//! terminating whitespace. Only 8-bit samples (maxval <= 255) are supported.
//!
//! The header parser works on a prefix of the file, so the firmware can read
//! the header, then stream rows.

use crate::limits::MAX_PGM_SIDE;

/// Why a PGM was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PgmError {
    /// Does not start with `P5`.
    BadMagic,
    /// The header ended early (more bytes would be needed).
    TruncatedHeader,
    /// A header field is not a decimal number, or is out of range.
    BadHeaderField,
    /// maxval above 255 (16-bit samples) is not supported.
    SixteenBit,
    /// Fewer pixel bytes than width x height.
    TruncatedPixels { expected: usize, got: usize },
}

impl core::fmt::Display for PgmError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            PgmError::BadMagic => f.write_str("not a binary PGM (missing P5 magic)"),
            PgmError::TruncatedHeader => f.write_str("PGM header is truncated"),
            PgmError::BadHeaderField => f.write_str("PGM header field is not a valid number"),
            PgmError::SixteenBit => f.write_str("16-bit PGM (maxval > 255) is not supported"),
            PgmError::TruncatedPixels { expected, got } => {
                write!(f, "PGM pixel data truncated: {got} of {expected} bytes")
            }
        }
    }
}

impl core::error::Error for PgmError {}

/// A parsed PGM header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PgmHeader {
    pub width: u16,
    pub height: u16,
    pub maxval: u8,
    /// Offset of the first pixel byte.
    pub data_offset: usize,
}

fn is_space(byte: u8) -> bool {
    matches!(byte, b' ' | b'\t' | b'\n' | b'\r' | 0x0b | 0x0c)
}

struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    /// Skips whitespace and comments before a field.
    fn skip_separators(&mut self) -> Result<(), PgmError> {
        loop {
            match self.bytes.get(self.at) {
                None => return Err(PgmError::TruncatedHeader),
                Some(b'#') => {
                    while self.bytes.get(self.at).is_some_and(|&b| b != b'\n' && b != b'\r') {
                        self.at += 1;
                    }
                }
                Some(&b) if is_space(b) => self.at += 1,
                Some(_) => return Ok(()),
            }
        }
    }

    fn number(&mut self) -> Result<u32, PgmError> {
        self.skip_separators()?;
        let mut value: u32 = 0;
        let start = self.at;
        while let Some(&b) = self.bytes.get(self.at) {
            if !b.is_ascii_digit() {
                break;
            }
            value = value.checked_mul(10).and_then(|v| v.checked_add(u32::from(b - b'0'))).ok_or(PgmError::BadHeaderField)?;
            self.at += 1;
        }
        match self.bytes.get(self.at) {
            None => Err(PgmError::TruncatedHeader),
            _ if self.at == start => Err(PgmError::BadHeaderField),
            Some(&b) if is_space(b) || b == b'#' => Ok(value),
            Some(_) => Err(PgmError::BadHeaderField),
        }
    }
}

impl PgmHeader {
    /// Parses the header from a prefix of the file.
    pub fn parse(bytes: &[u8]) -> Result<PgmHeader, PgmError> {
        match bytes {
            [b'P', b'5', ..] => {}
            [] | [b'P'] => return Err(PgmError::TruncatedHeader),
            _ => return Err(PgmError::BadMagic),
        }
        let mut cursor = Cursor { bytes, at: 2 };
        match cursor.bytes.get(2) {
            None => return Err(PgmError::TruncatedHeader),
            Some(&b) if is_space(b) || b == b'#' => {}
            Some(_) => return Err(PgmError::BadMagic),
        }
        let width = cursor.number()?;
        let height = cursor.number()?;
        let maxval = cursor.number()?;
        if width == 0 || height == 0 || width > MAX_PGM_SIDE || height > MAX_PGM_SIDE || maxval == 0 {
            return Err(PgmError::BadHeaderField);
        }
        if maxval > 255 {
            return Err(PgmError::SixteenBit);
        }
        // A comment may sit between maxval and the raster; the line end that
        // closes it is then the single delimiting whitespace byte.
        if bytes.get(cursor.at) == Some(&b'#') {
            while bytes.get(cursor.at).is_some_and(|&b| b != b'\n' && b != b'\r') {
                cursor.at += 1;
            }
            if cursor.at >= bytes.len() {
                return Err(PgmError::TruncatedHeader);
            }
        }
        Ok(PgmHeader {
            width: width as u16,
            height: height as u16,
            maxval: maxval as u8,
            data_offset: cursor.at + 1,
        })
    }

    pub fn pixel_bytes(&self) -> usize {
        usize::from(self.width) * usize::from(self.height)
    }
}

/// A checked view of a whole PGM file.
#[derive(Clone, Copy, Debug)]
pub struct Pgm<'a> {
    header: PgmHeader,
    pixels: &'a [u8],
}

impl<'a> Pgm<'a> {
    /// Checks the header and that all pixel bytes are present (extra bytes are ignored).
    pub fn new_checked(bytes: &'a [u8]) -> Result<Pgm<'a>, PgmError> {
        let header = PgmHeader::parse(bytes)?;
        let expected = header.pixel_bytes();
        let available = bytes.len().saturating_sub(header.data_offset);
        if available < expected {
            return Err(PgmError::TruncatedPixels { expected, got: available });
        }
        Ok(Pgm { header, pixels: &bytes[header.data_offset..][..expected] })
    }

    pub fn header(&self) -> &PgmHeader {
        &self.header
    }
    pub fn width(&self) -> usize {
        usize::from(self.header.width)
    }
    pub fn height(&self) -> usize {
        usize::from(self.header.height)
    }
    /// All pixels, row-major.
    pub fn pixels(&self) -> &'a [u8] {
        self.pixels
    }
    /// Row `j`, or None past the last row.
    pub fn row(&self, j: usize) -> Option<&'a [u8]> {
        (j < self.height()).then(|| &self.pixels[j * self.width()..][..self.width()])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_header_with_comments() {
        let file = b"P5\n# made by hand\n3 # width\n2\n255\n\x01\x02\x03\x04\x05\x06";
        let pgm = Pgm::new_checked(file).unwrap();
        assert_eq!((pgm.width(), pgm.height()), (3, 2));
        assert_eq!(pgm.row(1), Some(&[4u8, 5, 6][..]));
        assert_eq!(pgm.row(2), None);
    }

    #[test]
    fn binary_data_may_start_with_whitespace_bytes() {
        let file = b"P5 2 1 255 \n\x20";
        let pgm = Pgm::new_checked(file).unwrap();
        assert_eq!(pgm.pixels(), b"\n\x20");
    }

    #[test]
    fn refuses_damage() {
        assert_eq!(PgmHeader::parse(b"P6\n1 1\n255\n").unwrap_err(), PgmError::BadMagic);
        assert_eq!(PgmHeader::parse(b"P5\n12 1").unwrap_err(), PgmError::TruncatedHeader);
        assert_eq!(PgmHeader::parse(b"P5\n1x 1 255\n").unwrap_err(), PgmError::BadHeaderField);
        assert_eq!(PgmHeader::parse(b"P5\n0 1 255\n").unwrap_err(), PgmError::BadHeaderField);
        assert_eq!(PgmHeader::parse(b"P5\n1 1 65535\n").unwrap_err(), PgmError::SixteenBit);
        assert_eq!(PgmHeader::parse(b"P5\n99999999999 1 255\n").unwrap_err(), PgmError::BadHeaderField);
        assert_eq!(
            Pgm::new_checked(b"P5\n2 2\n255\n\x01\x02\x03").unwrap_err(),
            PgmError::TruncatedPixels { expected: 4, got: 3 }
        );
    }
}
