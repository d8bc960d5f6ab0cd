//! Minimal PGM (P5) header parsing for the semihosting row source.
//!
//! TODO(foundation): replace with `flatland_core::pgm` once it lands; this is
//! the one function to swap. It handles what netpbm allows: whitespace and
//! `#` comments between the tokens, maxval 1..=255, one whitespace byte
//! before the pixels.

/// A parsed P5 header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PgmHeader {
    pub width: u16,
    pub height: u16,
    pub maxval: u8,
    /// Offset of the first pixel byte.
    pub data_offset: usize,
}

/// Why a header was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum PgmHeaderError {
    NotP5,
    /// The header did not end within the bytes given.
    Incomplete,
    BadNumber,
    /// Not 8-bit (maxval > 255) or zero-sized.
    Unsupported,
}

/// Parses the header at the start of `bytes`.
pub fn parse_pgm_header(bytes: &[u8]) -> Result<PgmHeader, PgmHeaderError> {
    if bytes.len() < 2 {
        return Err(PgmHeaderError::Incomplete);
    }
    if &bytes[..2] != b"P5" {
        return Err(PgmHeaderError::NotP5);
    }
    let mut position = 2;
    let mut numbers = [0u32; 3];
    for number in numbers.iter_mut() {
        // Whitespace and comments before the token.
        loop {
            match bytes.get(position) {
                None => return Err(PgmHeaderError::Incomplete),
                Some(b'#') => {
                    while bytes.get(position).is_some_and(|&b| b != b'\n') {
                        position += 1;
                    }
                }
                Some(b) if b.is_ascii_whitespace() => position += 1,
                Some(_) => break,
            }
        }
        let start = position;
        while bytes.get(position).is_some_and(u8::is_ascii_digit) {
            *number = number
                .checked_mul(10)
                .and_then(|n| n.checked_add(u32::from(bytes[position] - b'0')))
                .ok_or(PgmHeaderError::BadNumber)?;
            position += 1;
        }
        if position == start {
            return Err(PgmHeaderError::BadNumber);
        }
    }
    // Exactly one whitespace byte separates maxval from the pixels.
    match bytes.get(position) {
        None => return Err(PgmHeaderError::Incomplete),
        Some(b) if b.is_ascii_whitespace() => position += 1,
        Some(_) => return Err(PgmHeaderError::BadNumber),
    }
    let [width, height, maxval] = numbers;
    let width = u16::try_from(width).map_err(|_| PgmHeaderError::Unsupported)?;
    let height = u16::try_from(height).map_err(|_| PgmHeaderError::Unsupported)?;
    let maxval = u8::try_from(maxval).map_err(|_| PgmHeaderError::Unsupported)?;
    if width == 0 || height == 0 || maxval == 0 {
        return Err(PgmHeaderError::Unsupported);
    }
    Ok(PgmHeader { width, height, maxval, data_offset: position })
}
