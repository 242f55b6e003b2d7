//! The streaming WAV reader (issue 14, item 4) against the whole-file one
//! (`read_wav_bytes`, the oracle): the same samples whatever the block
//! sizes, the same clipping count, and the same refusals with the same
//! messages, on generated files and on corrupted bytes.
#![allow(clippy::unwrap_used)]

use chirpmap_audio::filter::paper_highpass;
use chirpmap_audio::stream::{BlockSource, Filtered, for_windows};
use chirpmap_audio::wav::WavStream;
use chirpmap_audio::{AudioError, read_wav_bytes};
use proptest::prelude::*;
use std::path::PathBuf;

fn file(name: &str, bytes: &[u8]) -> PathBuf {
    let d = std::env::temp_dir().join(format!("chirpmap-wav-stream-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    let p = d.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// A WAV with `extra` chunks (odd lengths padded) before `data`.
fn wav_bytes(tag: u16, channels: u16, rate: u32, bits: u16, extra: &[Vec<u8>], data: &[u8]) -> Vec<u8> {
    let mut body = b"WAVE".to_vec();
    body.extend_from_slice(b"fmt ");
    body.extend_from_slice(&16u32.to_le_bytes());
    body.extend_from_slice(&tag.to_le_bytes());
    body.extend_from_slice(&channels.to_le_bytes());
    body.extend_from_slice(&rate.to_le_bytes());
    let block = channels.wrapping_mul(bits) / 8;
    body.extend_from_slice(&rate.wrapping_mul(u32::from(block)).to_le_bytes());
    body.extend_from_slice(&block.to_le_bytes());
    body.extend_from_slice(&bits.to_le_bytes());
    for payload in extra {
        body.extend_from_slice(b"LIST");
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

/// Reads channel `ch` of `path` in blocks of `block` frames.
fn stream_all(path: &std::path::Path, ch: usize, block: usize) -> Result<(Vec<f32>, usize), AudioError> {
    let mut s = WavStream::open(path, ch)?;
    let mut out = Vec::new();
    while s.read_block(&mut out, block)? > 0 {}
    Ok((out, s.clipped_samples()))
}

/// Both readers on the same bytes: equal samples and clipping, or equal errors.
fn agree(bytes: &[u8], name: &str, block: usize) {
    let p = file(name, bytes);
    let whole = read_wav_bytes(bytes);
    let streamed = stream_all(&p, 0, block);
    match (whole, streamed) {
        (Ok(rec), Ok((x, clipped))) => {
            let want = &rec.channels[0];
            assert_eq!(x.len(), want.len());
            assert!(x.iter().zip(want).all(|(a, b)| a.to_bits() == b.to_bits()), "samples differ");
            assert_eq!(clipped, rec.clipped_samples);
        }
        (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string()),
        (a, b) => panic!("whole: {:?}, streamed: {:?}", a.map(|r| r.len_samples()), b.map(|r| r.0.len())),
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn same_samples_as_the_whole_file_reader(
        fmt in 0usize..4,
        channels in 1u16..4,
        ch_pick in 0u16..4,
        frames in 1usize..700,
        block in 1usize..300,
        extra in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..9), 0..3),
        seed in any::<u64>(),
        bad_at in any::<proptest::sample::Index>(),
        bad in prop_oneof![Just(f32::NAN), Just(f32::INFINITY), Just(f32::NEG_INFINITY)],
    ) {
        let (tag, bits) = [(1u16, 16u16), (1, 24), (1, 32), (3, 32)][fmt];
        let width = usize::from(bits / 8);
        let mut r = seed | 1;
        let mut data: Vec<u8> = (0..frames * usize::from(channels) * width)
            .map(|_| { r ^= r << 13; r ^= r >> 7; r ^= r << 17; (r >> 24) as u8 })
            .collect();
        let ch = usize::from(ch_pick % channels);
        if tag == 3 {
            // Floats within ±1.2 (some clipped).
            for (i, s) in data.chunks_exact_mut(4).enumerate() {
                let v = ((i * 7919) % 2400) as f32 / 1000.0 - 1.2;
                s.copy_from_slice(&v.to_le_bytes());
            }
            // One non-finite sample, in any channel: both readers refuse the
            // file with the same message, naming its frame and channel.
            let at = bad_at.index(data.len() / 4);
            let mut broken = data.clone();
            broken[4 * at..4 * at + 4].copy_from_slice(&bad.to_le_bytes());
            let bytes = wav_bytes(tag, channels, 48_000, bits, &extra, &broken);
            let p = file(&format!("bad{fmt}-{channels}-{frames}.wav"), &bytes);
            let whole = read_wav_bytes(&bytes).unwrap_err().to_string();
            let streamed = stream_all(&p, ch, block).unwrap_err().to_string();
            prop_assert_eq!(&whole, &streamed);
            let named = format!("float sample {} of channel {} is ", at / usize::from(channels), at % usize::from(channels));
            prop_assert!(whole.starts_with(&named), "{}", whole);
        }
        let bytes = wav_bytes(tag, channels, 48_000, bits, &extra, &data);
        let p = file(&format!("p{fmt}-{channels}-{frames}.wav"), &bytes);
        let rec = read_wav_bytes(&bytes).unwrap();
        let (x, clipped) = stream_all(&p, ch, block).unwrap();
        prop_assert_eq!(clipped, rec.clipped_samples);
        prop_assert!(x.iter().zip(&rec.channels[ch]).all(|(a, b)| a.to_bits() == b.to_bits()));
        prop_assert_eq!(x.len(), rec.len_samples());
    }

    #[test]
    fn corrupted_files_are_refused_alike(cut in 0usize..200, flip in 0usize..200, byte in any::<u8>(), block in 1usize..50) {
        let data: Vec<u8> = (0..120u8).collect();
        let mut bytes = wav_bytes(1, 2, 8000, 16, &[vec![1, 2, 3]], &data);
        if flip < bytes.len() {
            bytes[flip] = byte;
        }
        bytes.truncate(cut.max(1));
        agree(&bytes, &format!("c{cut}-{flip}.wav"), block);
    }
}

#[test]
fn refusals_match_the_whole_file_reader() {
    let data = vec![0u8; 40];
    for (name, bytes) in [
        ("empty", Vec::new()),
        ("riff-only", b"RIFF\x00\x00".to_vec()),
        ("rf64", b"RF64\x00\x00\x00\x00WAVEfmt ".to_vec()),
        ("8bit", wav_bytes(1, 1, 8000, 8, &[], &data)),
        ("adpcm", wav_bytes(2, 1, 8000, 16, &[], &data)),
        ("rate0", wav_bytes(1, 1, 0, 16, &[], &data)),
        ("fast", wav_bytes(1, 1, 4_000_000, 16, &[], &data)),
        ("nochannels", wav_bytes(1, 0, 8000, 16, &[], &data)),
        ("noframe", wav_bytes(1, 3, 8000, 32, &[], &[0u8; 8])),
        ("big-float", wav_bytes(3, 1, 8000, 32, &[], &1000.0f32.to_le_bytes().repeat(4))),
    ] {
        agree(&bytes, name, 7);
    }
    // Declared longer than held.
    let mut cut = wav_bytes(1, 1, 8000, 16, &[], &data);
    cut.truncate(cut.len() - 10);
    agree(&cut, "cut", 7);
    let p = file("two.wav", &wav_bytes(1, 2, 8000, 16, &[], &data));
    let e = WavStream::open(&p, 2).unwrap_err();
    assert!(matches!(e, AudioError::NoSuchChannel { requested: 2, available: 2 }), "{e}");
}

/// A `BlockSource` over a vector, blocks of at most `block` samples.
struct Mem(Vec<f32>, usize, usize);
impl BlockSource for Mem {
    fn read(&mut self, out: &mut Vec<f32>, max: usize) -> Result<usize, AudioError> {
        let n = max.min(self.2).min(self.0.len() - self.1);
        out.extend_from_slice(&self.0[self.1..self.1 + n]);
        self.1 += n;
        Ok(n)
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    /// The block-wise high-pass gives `Sos::filter_in_place`'s samples bit
    /// for bit, and windows of a second read are those samples.
    #[test]
    fn filtered_stream_equals_whole_signal_filter(
        n in 1usize..5000,
        block in 1usize..700,
        seed in any::<u64>(),
        starts in proptest::collection::vec(0usize..5000, 0..20),
    ) {
        let mut r = seed | 1;
        let x: Vec<f32> = (0..n).map(|_| { r ^= r << 13; r ^= r >> 7; r ^= r << 17; (r >> 40) as f32 / 8.4e6 - 1.0 }).collect();
        let sos = paper_highpass(8000.0).unwrap();
        let mut want = x.clone();
        sos.filter_in_place(&mut want);
        let mut f = Filtered::new(Mem(x.clone(), 0, block), &sos);
        let mut got = Vec::new();
        while f.read(&mut got, 1 << 16).unwrap() > 0 {}
        prop_assert!(got.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()));
        prop_assert_eq!(got.len(), n);
        let mut windows: Vec<(usize, usize)> = starts.iter().map(|&s| (s.min(n), (s + 300).min(n))).collect();
        windows.sort_unstable();
        let mut f = Filtered::new(Mem(x, 0, block), &sos);
        let mut seen = 0;
        for_windows(&mut f, n, &windows, |i, w| {
            let (s, e) = windows[i];
            assert!(w.iter().zip(&want[s..e]).all(|(a, b)| a.to_bits() == b.to_bits()));
            assert_eq!(w.len(), e - s);
            seen += 1;
        }).unwrap();
        prop_assert_eq!(seen, windows.len());
    }
}
