//! The protocol's checks (host `#[test]`s and `cargo fw-test` on the emulated
//! M4, listed in [`crate::selftest`]).

use super::*;
use crate::selftest::{ensure, xorshift32, Outcome as Check};

fn sample_rig(distortion: Option<[f64; 5]>) -> RigRecord {
    RigRecord {
        camera: Intrinsics {
            width: 320,
            height: 240,
            fx: 277.0,
            fy: 281.25,
            cx: 159.5,
            cy: 119.5,
            distortion: distortion.map(Distortion::from_coefficients),
            readout_ms: 0.0,
        },
        mount: Mount { height_mm: 300.0, tilt_deg: 40.0, roll_deg: 0.0, yaw_deg: 0.0 },
        aoi: Aoi { half_width_mm: 250.0, near_mm: 450.0, far_mm: 1400.0 },
    }
}

use crate::report::{sample_report, NotJudged};

/// Counters numbered 1 to 10 in wire order.
fn sample_stats() -> LinkStats {
    LinkStats {
        decoder: DecoderStats { garbage_bytes: 2, truncated: 3, too_long: 4, bad_checksum: 5, unknown_type: 6, bad_field: 7 },
        frame_loop: LoopStats { frames: 1, out_of_order: 8, frame_gaps: 9, aborted: 10 },
    }
}

/// Frame 3's odometry message with these sensors' fields.
fn sample_odometry(pose: Option<Pose>, attitude: Option<Attitude>) -> Odometry {
    Odometry { frame: 3, t_s: 0.3, pose, attitude }
}

/// Every decoded message of `bytes`, in order; errors are dropped (and counted).
fn decode_all(decoder: &mut Decoder, bytes: &[u8]) -> heapless::Vec<Message, 16> {
    let mut messages = heapless::Vec::new();
    for &byte in bytes {
        if let Some(Ok(message)) = decoder.push(byte) {
            let _ = messages.push(message);
        }
    }
    messages
}

fn round_trip(message: Message) -> Check {
    let line = encode_line(&message).map_err(|_| "encode failed")?;
    let mut decoder = Decoder::new();
    let decoded = decode_all(&mut decoder, line.as_bytes());
    ensure(decoded.as_slice() == [message], "decoded message differs from the encoded one")?;
    ensure(decoder.stats() == DecoderStats::ZERO, "clean line counted as an error")
}

pub fn every_message_round_trips() -> Check {
    let messages = [
        Message::Ready,
        Message::Hello(sample_rig(None)),
        Message::Rig(sample_rig(Some([-0.28, 0.07, 1e-4, -2.5e-4, 0.0]))),
        Message::Odometry(sample_odometry(Some(Pose { x_mm: -0.1, z_mm: 19.43, yaw_deg: -0.0477 }), None)),
        Message::Odometry(sample_odometry(None, Some(Attitude { pitch_deg: 0.83, roll_deg: -0.0 }))),
        Message::Odometry(sample_odometry(
            Some(Pose { x_mm: 2.5, z_mm: -7.0, yaw_deg: 359.9 }),
            Some(Attitude { pitch_deg: -1.25, roll_deg: 0.004 }),
        )),
        Message::Odometry(sample_odometry(None, None)),
        Message::Frame(sample_report()),
        Message::Frame(FrameReport::default()),
        // A drop's depth: obstacle_h_mm is signed on the wire (issue 14).
        Message::Frame(FrameReport { obstacle_h_mm: Some(-150), ..sample_report() }),
        // Frames not judged, each reason (version 3).
        Message::Frame(FrameReport::not_judged(9, 8, NotJudged::NoMotion)),
        Message::Frame(FrameReport::not_judged(9, 9, NotJudged::AfterGap)),
        Message::Stats(sample_stats()),
        Message::Fault(Fault { code: FaultCode::FrameRead, frame: 12 }),
        Message::End,
    ];
    for message in messages {
        round_trip(message)?;
    }
    for code in FaultCode::ALL {
        round_trip(Message::Fault(Fault { code, frame: u32::MAX }))?;
    }
    Ok(())
}

/// rig.toml's values survive record -> `Rig` -> record, with and without a lens.
pub fn rig_converts_both_ways() -> Check {
    // A rig `Rig::new_checked` accepts (sample_rig is only a wire sample).
    let valid = |distortion| {
        let sample = sample_rig(distortion);
        RigRecord {
            camera: Intrinsics { width: 256, height: 256, fx: 240.0, fy: 240.0, cx: 127.5, cy: 127.5, ..sample.camera },
            mount: Mount { height_mm: 400.0, tilt_deg: 32.0, ..sample.mount },
            ..sample
        }
    };
    for distortion in [None, Some([-0.28, 0.07, 1e-4, -2.5e-4, 0.01])] {
        for (roll_deg, yaw_deg) in [(0.0, 0.0), (1.5, -2.25)] {
            let record = valid(distortion);
            let record = RigRecord { mount: Mount { roll_deg, yaw_deg, ..record.mount }, ..record };
            let rig = Rig::try_from(&record).map_err(|_| "valid rig refused")?;
            ensure(RigRecord::from(&rig) == record, "rig record changed through the rig")?;
        }
    }
    let rolled = RigRecord { mount: Mount { roll_deg: 45.0, ..valid(None).mount }, ..valid(None) };
    ensure(Rig::try_from(&rolled) == Err(RigError::Roll), "an impossible roll was accepted")?;
    let refused = RigRecord { mount: Mount { tilt_deg: 90.0, ..valid(None).mount }, ..valid(None) };
    ensure(Rig::try_from(&refused) == Err(RigError::Tilt), "an impossible rig was accepted")
}

pub fn floats_round_trip_bit_for_bit() -> Check {
    let awkward = [0.1, 1.0 / 3.0, 301.70001220703125, 1e-300, -1.7976931348623157e308, 5e-324, 123456789.125];
    for value in awkward {
        let pose = Pose { x_mm: -value, z_mm: value, yaw_deg: 0.0 };
        let attitude = Attitude { pitch_deg: value, roll_deg: -value };
        let message = Message::Odometry(Odometry { frame: 0, t_s: value, pose: Some(pose), attitude: Some(attitude) });
        let line = encode_line(&message).map_err(|_| "encode failed")?;
        // Six floats of at most 26 characters each, and the frame.
        ensure(line.len() < 180, "float encoding is unbounded")?;
        round_trip(message)?;
    }
    Ok(())
}

pub fn longest_rig_fits_a_line() -> Check {
    let long = -1.2345678901234567e-300;
    let rig = RigRecord {
        camera: Intrinsics {
            width: u16::MAX,
            height: u16::MAX,
            fx: long,
            fy: long,
            cx: long,
            cy: long,
            distortion: Some(Distortion::from_coefficients([long; 5])),
            readout_ms: 0.0,
        },
        mount: Mount { height_mm: long, tilt_deg: long, roll_deg: long, yaw_deg: long },
        aoi: Aoi { half_width_mm: long, near_mm: long, far_mm: long },
    };
    round_trip(Message::Rig(rig))
}

pub fn known_lines_match_documentation() -> Check {
    // The odometry examples in firmware/PROTOCOL.md: wheels and IMU, wheels, IMU, neither.
    let pose = Some(Pose { x_mm: 0.0, z_mm: 100.0, yaw_deg: 0.0 });
    let attitude = Some(Attitude { pitch_deg: 0.25, roll_deg: -0.5 });
    let documented = [
        (pose, attitude, "$FLODO,1,0.1,0,100,0,0.25,-0.5*52\r\n"),
        (pose, None, "$FLODO,1,0.1,0,100,0*4D\r\n"),
        (None, attitude, "$FLODO,1,0.1,0.25,-0.5*4F\r\n"),
        (None, None, "$FLODO,1,0.1*50\r\n"),
    ];
    for (pose, attitude, expected) in documented {
        let line = encode_line(&Message::Odometry(Odometry { frame: 1, t_s: 0.1, pose, attitude }))
            .map_err(|_| "encode failed")?;
        ensure(line.as_str() == expected, "odometry line differs from PROTOCOL.md")?;
    }
    Ok(())
}

/// The field tables' order is the wire's (PROTOCOL.md): a round trip
/// alone would not see two fields swapped.
pub fn tables_keep_the_documented_order() -> Check {
    let documented = [
        (Message::Stats(sample_stats()), "$FLSTA,1,2,3,4,5,6,7,8,9,10*7C\r\n"),
        (Message::Frame(sample_report()), "$FLFRM,7,6,1,820,-120,,12345,67,-5,125,-3,1003,,-1500,120,-7,1,ok*70\r\n"),
    ];
    for (message, expected) in documented {
        let line = encode_line(&message).map_err(|_| "encode failed")?;
        ensure(line.as_str() == expected, "a table's order differs from PROTOCOL.md")?;
    }
    Ok(())
}

pub fn non_finite_is_refused_by_encoder() -> Check {
    let refused = [
        Odometry { frame: 0, t_s: f64::NAN, pose: None, attitude: None },
        Odometry { frame: 0, t_s: 0.0, pose: Some(Pose { yaw_deg: f64::INFINITY, ..Pose::default() }), attitude: None },
        Odometry { frame: 0, t_s: 0.0, pose: None, attitude: Some(Attitude { pitch_deg: 0.0, roll_deg: f64::NAN }) },
    ];
    for odometry in refused {
        ensure(encode_line(&Message::Odometry(odometry)) == Err(EncodeError::NonFinite), "NaN or infinity was encoded")?;
    }
    Ok(())
}

fn first_error(bytes: &[u8]) -> Option<DecodeError> {
    let mut decoder = Decoder::new();
    bytes.iter().find_map(|&b| match decoder.push(b) {
        Some(Err(error)) => Some(error),
        _ => None,
    })
}

pub fn malformed_lines_give_typed_errors() -> Check {
    let cases: [(&[u8], DecodeError); 18] = [
        (b"$FLEND*00\r\n", DecodeError::BadChecksum),
        (b"$FLEND\r\n", DecodeError::MissingChecksum),
        (b"$FLEND*G1\r\n", DecodeError::MissingChecksum),
        (b"$FLXYZ*51\r\n", DecodeError::UnknownType),
        (b"$FLEND,1*58\r\n", DecodeError::FieldCount),
        // Odometry has 2, 4, 5 or 7 fields; absent sensors leave theirs out, never empty.
        (b"$FLODO*4E\r\n", DecodeError::FieldCount),
        (b"$FLODO,1,2,3*52\r\n", DecodeError::FieldCount),
        (b"$FLODO,1,0.1,0,100,0,0*51\r\n", DecodeError::FieldCount),
        (b"$FLODO,1,0.1,,,,0.25,-0.5*63\r\n", DecodeError::BadField { index: 3 }),
        (b"$FLODO,1,0.1,0.25,x*31\r\n", DecodeError::BadField { index: 4 }),
        (b"$FLODO,x,0,0,0,0*1A\r\n", DecodeError::BadField { index: 1 }),
        (b"$FLODO,1,0,inf,0,0*02\r\n", DecodeError::BadField { index: 3 }),
        (b"$FLRIG,9,1,1,1,1,1,1,,,,,,1,1,1,1,1*72\r\n", DecodeError::UnsupportedVersion),
        (b"$FLRDY,2*5B\r\n", DecodeError::UnsupportedVersion),
        // A version-2 frame (no status) is one field short; a status must be a known name.
        (b"$FLFRM,2,0,0,,,,310,0,12,-4,3,1998,,-250,85,-12,*56\r\n", DecodeError::FieldCount),
        (b"$FLFRM,2,0,0,,,,310,0,12,-4,3,1998,,-250,85,-12,,late*66\r\n", DecodeError::BadField { index: 18 }),
        (b"$FLFRM,2,0,0,,,,310,0,12,-4,3,1998,,-250,85,-12,,*7A\r\n", DecodeError::BadField { index: 18 }),
        (b"$FLEN$FLEND*45\r\n", DecodeError::Truncated),
    ];
    for (bytes, expected) in cases {
        if first_error(bytes) != Some(expected) {
            return Err(expected.as_str());
        }
    }
    Ok(())
}

pub fn decoder_resynchronises_after_garbage() -> Check {
    let mut stream: heapless::Vec<u8, 2048> = heapless::Vec::new();
    let end = encode_line(&Message::End).map_err(|_| "encode failed")?;
    let frame = encode_line(&Message::Frame(sample_report())).map_err(|_| "encode failed")?;
    let mut append = |bytes: &[u8]| stream.extend_from_slice(bytes).map_err(|_| "test buffer full");
    append(b"\x00\xffnoise")?; // 7 garbage bytes
    append(&frame.as_bytes()[..20])?; // truncated by the next `$`
    append(end.as_bytes())?;
    append(&[b'$'; 1])?;
    append(&[b'A'; MAX_LINE + 10])?; // too long, skipped to the line end
    append(b"\r\n")?;
    append(frame.as_bytes())?;
    let mut decoder = Decoder::new();
    let messages = decode_all(&mut decoder, &stream);
    ensure(messages.as_slice() == [Message::End, Message::Frame(sample_report())], "lost a good line")?;
    let stats = decoder.stats();
    ensure(stats.garbage_bytes == 7, "garbage bytes miscounted")?;
    ensure(stats.truncated == 1, "truncated line miscounted")?;
    ensure(stats.too_long == 1, "overlong line miscounted")
}

pub fn random_bytes_never_panic_and_valid_lines_survive() -> Check {
    let mut state = 0x2545_F491;
    let mut decoder = Decoder::new();
    // Random bytes biased towards the protocol's own characters.
    for _ in 0..20_000 {
        let byte = match xorshift32(&mut state) % 8 {
            0 => b'$',
            1 => b'\n',
            2 => b',',
            3 => b'*',
            _ => (xorshift32(&mut state) & 0xFF) as u8,
        };
        let _ = decoder.push(byte);
    }
    // After a line end, a good line decodes whatever came before.
    let _ = decoder.push(b'\n');
    let line = encode_line(&Message::Frame(sample_report())).map_err(|_| "encode failed")?;
    let messages = decode_all(&mut decoder, line.as_bytes());
    ensure(messages.as_slice() == [Message::Frame(sample_report())], "decoder did not recover")
}
