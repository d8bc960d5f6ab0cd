//! The PGM reader: header parser, checked view, and the host's frame reader.
#![no_main]

use flatland_core::pgm::{Pgm, PgmHeader};
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let header = PgmHeader::parse(data);
    match Pgm::new_checked(data) {
        Ok(pgm) => {
            let header = header.expect("new_checked accepted what parse refused");
            assert_eq!(pgm.header(), &header);
            assert!(header.data_offset <= data.len());
            assert_eq!(pgm.pixels().len(), pgm.width() * pgm.height());
            for j in 0..pgm.height() {
                assert_eq!(pgm.row(j).map(<[u8]>::len), Some(pgm.width()));
            }
            assert!(pgm.row(pgm.height()).is_none());
        }
        Err(_) => {}
    }
    let frame = flatland_host::recording::parse_frame(Path::new("fuzz.pgm"), data);
    if let Ok(frame) = frame {
        assert_eq!(frame.pixels.len(), frame.width * frame.height);
    }
});
