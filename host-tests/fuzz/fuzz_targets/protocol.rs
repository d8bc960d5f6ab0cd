//! The serial protocol decoder: arbitrary bytes never panic, counters only
//! grow, and every message it accepts re-encodes to a line that decodes to
//! the same message.
#![no_main]

use flatland_core::limits::MAX_LINE;
use flatland_core::protocol::{decode_line, encode_line, Decoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = decode_line(data);
    let mut decoder = Decoder::new();
    for &byte in data {
        let before = decoder.stats();
        if let Some(Ok(message)) = decoder.push(byte) {
            let line = encode_line(&message).expect("a decoded message must re-encode");
            assert!(line.len() <= MAX_LINE);
            let mut again = Decoder::new();
            let decoded: Vec<_> = line.bytes().filter_map(|b| again.push(b)).collect();
            assert_eq!(decoded, [Ok(message)]);
        }
        let after = decoder.stats();
        assert!(after.garbage_bytes >= before.garbage_bytes && after.bad_field >= before.bad_field);
    }
});
