//! Fuzz harness (proptest) for the WAV reader `read_wav_bytes` and the
//! `[synth]` scene parser (issue 8, "Fuzzing, kept"): arbitrary bytes and
//! valid files with hostile header fields never panic or allocate beyond
//! the cap, and what is accepted keeps the reader's promises.
//!
//! Bounded for CI; `CHIRPMAP_FUZZ_CASES=N` raises the number of cases.
#![allow(clippy::unwrap_used)]

use chirpmap_audio::error::MAX_FLOAT_SAMPLE;
use chirpmap_audio::read_wav_bytes;
use chirpmap_audio::synth::{parse_scene_with_synth, synth_memory_bytes};
use chirpmap_audio::wav::{MAX_CHANNELS, MAX_SAMPLE_RATE_HZ};
use proptest::prelude::*;

fn cases(default: u32) -> u32 {
    std::env::var("CHIRPMAP_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn u32_field() -> impl Strategy<Value = u32> {
    prop_oneof![Just(0u32), Just(1), Just(8000), Just(48_000), Just(1_000_001), Just(u32::MAX), any::<u32>()]
}

fn u16_field() -> impl Strategy<Value = u16> {
    prop_oneof![Just(0u16), Just(1), Just(2), Just(3), Just(16), Just(24), Just(32), Just(0xFFFE), any::<u16>()]
}

/// A RIFF/WAVE file with the given header fields, chunk lengths and data.
#[allow(clippy::too_many_arguments)]
fn wav(tag: u16, ch: u16, rate: u32, bits: u16, fmt_len: u32, data_len: u32, data: &[u8], riff_len: u32) -> Vec<u8> {
    let mut v = b"RIFF".to_vec();
    v.extend(riff_len.to_le_bytes());
    v.extend(b"WAVEfmt ");
    v.extend(fmt_len.to_le_bytes());
    v.extend(tag.to_le_bytes());
    v.extend(ch.to_le_bytes());
    v.extend(rate.to_le_bytes());
    v.extend(rate.wrapping_mul(u32::from(ch)).to_le_bytes());
    v.extend(ch.wrapping_mul(bits / 8).to_le_bytes());
    v.extend(bits.to_le_bytes());
    // Extensible subformat (24 more bytes) so tag 0xFFFE can be read.
    v.extend([0u8; 8]);
    v.extend(tag.to_le_bytes());
    v.extend([0u8; 14]);
    v.truncate(20 + fmt_len.min(40) as usize);
    v.extend(b"data");
    v.extend(data_len.to_le_bytes());
    v.extend(data);
    v
}

fn check(bytes: &[u8]) {
    if let Ok(r) = read_wav_bytes(bytes) {
        assert!(r.sample_rate_hz >= 1 && r.sample_rate_hz <= MAX_SAMPLE_RATE_HZ);
        assert!(!r.channels.is_empty() && r.channels.len() <= usize::from(MAX_CHANNELS));
        let n = r.len_samples();
        assert!(n >= 1 && r.channels.iter().all(|c| c.len() == n));
        // Decoding never grows beyond 2× the file (16-bit → f32).
        assert!(n * r.channels.len() * 4 <= 2 * bytes.len());
        assert!(r.channels.iter().flatten().all(|v| v.is_finite() && f64::from(v.abs()) <= MAX_FLOAT_SAMPLE));
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases(256)))]

    #[test]
    fn fuzz_wav_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        check(&bytes);
    }

    #[test]
    fn fuzz_wav_hostile_headers(
        tag in prop_oneof![Just(1u16), Just(3), Just(0xFFFE), any::<u16>()],
        ch in u16_field(),
        rate in u32_field(),
        bits in u16_field(),
        fmt_len in prop_oneof![Just(16u32), Just(40), 0u32..48, Just(u32::MAX)],
        data in proptest::collection::vec(any::<u8>(), 0..512),
        data_len in prop_oneof![Just(None), Just(Some(0u32)), Just(Some(u32::MAX)), any::<u32>().prop_map(Some)],
        riff_len in any::<u32>(),
        float_scale in prop_oneof![Just(1.0f32), Just(1e30), Just(f32::NAN), Just(f32::INFINITY)],
    ) {
        let data: Vec<u8> = if tag == 3 && bits == 32 {
            data.chunks_exact(4)
                .flat_map(|c| (f32::from_le_bytes([c[0], c[1], c[2], c[3]]).clamp(-1.0, 1.0) * float_scale).to_le_bytes())
                .collect()
        } else {
            data
        };
        let len = data_len.unwrap_or(data.len() as u32);
        check(&wav(tag, ch, rate, bits, fmt_len, len, &data, riff_len));
    }

    #[test]
    fn fuzz_wav_mutated_valid_file(
        edits in proptest::collection::vec((0usize..120, any::<u8>()), 1..10),
        cut in 0usize..140,
    ) {
        let data: Vec<u8> = (0..64i16).flat_map(|i| (i * 500).to_le_bytes()).collect();
        let mut bytes = wav(1, 2, 48_000, 16, 16, data.len() as u32, &data, 0);
        for (at, b) in edits {
            if let Some(x) = bytes.get_mut(at) {
                *x = b;
            }
        }
        bytes.truncate(bytes.len().saturating_sub(cut % 8));
        check(&bytes);
    }

    #[test]
    fn fuzz_synth_table_never_panics(
        chirps in prop_oneof![Just("0".to_string()), Just("50".to_string()), Just("18446744073709551615".to_string()), Just("-1".to_string())],
        gap in prop_oneof![Just("1.0"), Just("nan"), Just("inf"), Just("-1.0"), Just("1e300")],
        rate in prop_oneof![Just("48000"), Just("0"), Just("4294967295"), Just("8000")],
        pose in prop_oneof![Just("0.01"), Just("1e-300"), Just("0.0"), Just("nan")],
        bits in prop_oneof![Just("\"16\""), Just("\"f32\""), Just("\"7\""), Just("16")],
        listeners in 0usize..4,
    ) {
        let mut text = format!(
            "[synth]\nchirps = {chirps}\ngap_s = {gap}\nsample_rate_hz = {rate}\npose_period_s = {pose}\nbits = {bits}\n"
        );
        for i in 0..listeners {
            text.push_str(&format!("[[listeners]]\nstart = [{}, 10.0]\nspeed = 0.0\n", i as f64));
        }
        if let Ok((scene, cfg)) = parse_scene_with_synth(&text) {
            scene.validate().unwrap();
            cfg.validate().unwrap();
            let bytes = synth_memory_bytes(&scene, &cfg);
            prop_assert!(bytes.is_finite() && bytes > 0.0);
        }
    }
}
