//! WAV reader: formats, extra chunks, and bad input (issue 5).
#![allow(clippy::unwrap_used)]

use chirpmap_audio::{AudioError, SampleFormat, read_wav, read_wav_bytes, write_wav};
use proptest::prelude::*;

/// A canonical WAV header + data, with optional chunks before `data`.
fn wav_bytes(
    format_tag: u16,
    channels: u16,
    rate: u32,
    bits: u16,
    extra: &[(&[u8; 4], &[u8])],
    data: &[u8],
) -> Vec<u8> {
    let mut body = Vec::new();
    body.extend_from_slice(b"WAVE");
    body.extend_from_slice(b"fmt ");
    body.extend_from_slice(&16u32.to_le_bytes());
    body.extend_from_slice(&format_tag.to_le_bytes());
    body.extend_from_slice(&channels.to_le_bytes());
    body.extend_from_slice(&rate.to_le_bytes());
    let block = channels.wrapping_mul(bits) / 8;
    body.extend_from_slice(&rate.wrapping_mul(u32::from(block)).to_le_bytes());
    body.extend_from_slice(&block.to_le_bytes());
    body.extend_from_slice(&bits.to_le_bytes());
    for (id, payload) in extra {
        body.extend_from_slice(*id);
        body.extend_from_slice(&(payload.len() as u32).to_le_bytes());
        body.extend_from_slice(payload);
        if payload.len() % 2 == 1 {
            body.push(0);
        }
    }
    body.extend_from_slice(b"data");
    body.extend_from_slice(&(data.len() as u32).to_le_bytes());
    body.extend_from_slice(data);
    let mut out = b"RIFF".to_vec();
    out.extend_from_slice(&(body.len() as u32).to_le_bytes());
    out.extend(body);
    out
}

fn i16_data(v: &[i16]) -> Vec<u8> {
    v.iter().flat_map(|s| s.to_le_bytes()).collect()
}

#[test]
fn round_trips_every_supported_format_and_channel_count() {
    let dir = std::env::temp_dir().join(format!("chirpmap-wav-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let a: Vec<f32> = (0..1000).map(|i| ((i as f32) * 0.01).sin() * 0.8).collect();
    let b: Vec<f32> = a.iter().map(|v| -v * 0.5).collect();
    for (fmt, tol) in [
        (SampleFormat::Int(16), 0.5 / 32768.0),
        (SampleFormat::Int(24), 0.5 / 8_388_608.0),
        (SampleFormat::Int(32), 1e-7),
        (SampleFormat::Float32, 0.0),
    ] {
        let p = dir.join("x.wav");
        write_wav(&p, 44_100, fmt, &[&a, &b]).unwrap();
        let r = read_wav(&p).unwrap();
        assert_eq!(r.sample_rate_hz, 44_100);
        assert_eq!(r.format, fmt);
        assert_eq!(r.channels.len(), 2);
        for (ch, want) in r.channels.iter().zip([&a, &b]) {
            let d = ch.iter().zip(want.iter()).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
            assert!(d <= tol as f32 + 1e-7, "{fmt:?}: {d}");
        }
        assert_eq!(r.clipped_samples, 0);
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn skips_unknown_chunks_before_data() {
    let bytes = wav_bytes(
        1,
        1,
        48_000,
        16,
        &[(b"LIST", b"INFOISFT\x05\x00\x00\x00abc"), (b"guan", b"x")],
        &i16_data(&[1000, -1000, 0]),
    );
    let r = read_wav_bytes(&bytes).unwrap();
    assert_eq!(r.channels[0].len(), 3);
    assert!((r.channels[0][0] - 1000.0 / 32768.0).abs() < 1e-7);
}

#[test]
fn counts_clipped_samples() {
    let bytes = wav_bytes(1, 1, 48_000, 16, &[], &i16_data(&[32767, -32768, 5, 32767, 100]));
    assert_eq!(read_wav_bytes(&bytes).unwrap().clipped_samples, 3);
}

#[test]
fn truncated_file_is_a_clear_error() {
    let bytes = wav_bytes(1, 1, 48_000, 16, &[], &i16_data(&[1; 100]));
    for cut in [bytes.len() - 50, 30, 10] {
        let err = read_wav_bytes(&bytes[..cut]).unwrap_err();
        assert!(matches!(err, AudioError::Truncated(_)), "cut {cut}: {err}");
    }
}

#[test]
fn non_wav_is_a_clear_error() {
    let err = read_wav_bytes(b"ID3\x03\x00 this is an mp3, honest").unwrap_err();
    assert!(matches!(err, AudioError::NotWav(_)), "{err}");
    assert!(err.to_string().contains("RIFF"), "{err}");
    assert!(matches!(read_wav_bytes(b"").unwrap_err(), AudioError::NotWav(_)));
}

#[test]
fn unsupported_encodings_are_named() {
    // 8-bit PCM and A-law (format tag 6).
    let err = read_wav_bytes(&wav_bytes(1, 1, 8_000, 8, &[], &[128, 130, 126, 128])).unwrap_err();
    assert!(matches!(err, AudioError::Unsupported(_)), "{err}");
    let err = read_wav_bytes(&wav_bytes(6, 1, 8_000, 8, &[], &[1, 2, 3, 4])).unwrap_err();
    assert!(matches!(err, AudioError::Unsupported(_) | AudioError::NotWav(_)), "{err}");
}

#[test]
fn missing_channel_is_an_error() {
    let r = read_wav_bytes(&wav_bytes(1, 1, 48_000, 16, &[], &i16_data(&[1, 2]))).unwrap();
    assert!(matches!(r.channel(1), Err(AudioError::NoSuchChannel { requested: 1, available: 1 })));
}

// Fuzz harness: the reader must return (Ok or Err) on any bytes, never
// panic. CI runs the default 256 cases per property; for a longer run:
// `PROPTEST_CASES=20000000 cargo test -p chirpmap-audio --test integration wav::fuzz` (run once for
// issue 5: 20 M cases per property, 110 s, no panic).
proptest! {
    #[test]
    fn fuzz_arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        let _ = read_wav_bytes(&bytes);
    }

    #[test]
    fn fuzz_mutated_valid_files_never_panic(
        edits in proptest::collection::vec((0usize..200, any::<u8>()), 1..8),
        cut in 0usize..200,
        bits in prop_oneof![Just(16u16), Just(24), Just(32)],
        tag in prop_oneof![Just(1u16), Just(3), Just(0xFFFE)],
    ) {
        let mut b = wav_bytes(tag, 2, 48_000, bits, &[(b"LIST", b"abcd")], &[7u8; 96]);
        for (pos, val) in edits {
            if pos < b.len() { b[pos] = val; }
        }
        b.truncate(b.len().saturating_sub(cut));
        let _ = read_wav_bytes(&b);
    }
}

/// Issue 8, item 8: header fields a user (or a corrupt file) controls are
/// bounded before anything is allocated, with the field and limit named.
#[test]
fn hostile_header_sizes_are_refused_before_allocating() {
    let data = i16_data(&[1, 2, 3, 4]);
    let e = read_wav_bytes(&wav_bytes(1, 1, u32::MAX, 16, &[], &data)).unwrap_err().to_string();
    assert!(e.contains("sample rate 4294967295 Hz") && e.contains("at most 1000000 Hz"), "{e}");
    let e = read_wav_bytes(&wav_bytes(1, 300, 48_000, 16, &[], &vec![0u8; 600 * 2])).unwrap_err().to_string();
    assert!(e.contains("300 channels") && e.contains("at most 256"), "{e}");
    // The decoded size is estimated and checked against the cap.
    let e = chirpmap_audio::error::check_memory(|| "decoding".into(), 5 << 30, "hint").unwrap_err().to_string();
    assert!(e.contains("5.4 GB") && e.contains("cap of 4.3 GB"), "{e}");
}

/// Issue 8, item 16: a float WAV scaled ×1e30 is an error about the samples'
/// scale (it used to surface as an error about `--max-delta-d`).
#[test]
fn wrongly_scaled_float_wav_is_a_clear_error() {
    let samples: Vec<u8> = (0..100).flat_map(|i| ((i as f32 * 0.1).sin() * 1e30).to_le_bytes()).collect();
    let e = read_wav_bytes(&wav_bytes(3, 1, 48_000, 32, &[], &samples)).unwrap_err();
    assert!(matches!(e, AudioError::BadScale { .. }), "{e}");
    let msg = e.to_string();
    assert!(msg.contains("full scale is ±1") && msg.contains("e29") && !msg.contains("delta"), "{msg}");
    // A little over full scale is still read (and counted as clipped).
    let ok: Vec<u8> = [0.5f32, 1.5, -2.0].iter().flat_map(|v| v.to_le_bytes()).collect();
    assert_eq!(read_wav_bytes(&wav_bytes(3, 1, 48_000, 32, &[], &ok)).unwrap().clipped_samples, 2);
}
