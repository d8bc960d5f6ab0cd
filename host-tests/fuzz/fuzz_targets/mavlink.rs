//! The MAVLink input path: arbitrary bytes through core's frame decoder
//! never panic; counters only grow; every message it accepts converts to
//! a pose sample or a typed error; a frame it reads re-encodes and reads
//! back the same.
#![no_main]

use flatland_core::mavlink::{sample_from_local_position, sample_from_odometry, FrameDecoder, Inbound, Sender};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut decoder = FrameDecoder::new();
    let mut attitude = None;
    for &byte in data {
        let before = decoder.stats();
        match decoder.push(byte) {
            Some(Ok(Inbound::Odometry(odometry))) => {
                if let Ok(sample) = sample_from_odometry(&odometry) {
                    assert!(sample.t_s.is_finite());
                }
                let frame = Sender::default().encode(&odometry);
                let mut again = FrameDecoder::new();
                let read: Vec<_> = frame.as_bytes().iter().filter_map(|&b| again.push(b)).collect();
                assert_eq!(read.len(), 1);
                assert!(matches!(&read[0], Ok(Inbound::Odometry(o)) if o.time_usec == odometry.time_usec));
            }
            Some(Ok(Inbound::Attitude(latest))) => attitude = Some(latest),
            Some(Ok(Inbound::LocalPosition(position))) => {
                if let Some(attitude) = &attitude {
                    let _ = sample_from_local_position(&position, attitude);
                }
            }
            Some(Ok(Inbound::Heartbeat { .. })) | Some(Err(_)) | None => {}
        }
        let after = decoder.stats();
        assert!(after.garbage_bytes >= before.garbage_bytes && after.checksum >= before.checksum && after.foreign >= before.foreign);
    }
});
