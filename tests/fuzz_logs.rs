//! Seeded mutations of a real log (single-bit flips in every record type, random multi-byte
//! overwrites, truncations), read in-process by `analyze` and `info`: no panic, no hang, and no
//! damaged log taken as valid. Every mutation must be an error, except a multi-byte overwrite
//! that happens to leave the metrics unchanged (none is expected: every byte of a log is
//! under a CRC or a structural check).
//!
//! `MJSAFE_FUZZ_CASES` (default 3000) sets the number of analyses; `info` gets a tenth of them.
//! `scripts/fuzz-logs.sh` runs 100k+.

use std::collections::BTreeMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::time::{Duration, Instant};

use mjsafe::analyze::{self, AnalyzeError};
use mjsafe::episode::Episode;
use mjsafe::log::info;
use mjsafe::log::mcap::McapSink;
use mjsafe::log::read::ReadError;
use mjsafe::scenario;

/// A deterministic stream of draws from one seed.
use mjsafe::random::SplitMix64 as Rng;

/// The log of bicycle_obstacle.toml (12 s, 1.1 MB): a collision at t ≈ 3.7 s (min h −18.6),
/// three 1 MiB chunks.
fn real_log(dir: &Path) -> Vec<u8> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let loaded = scenario::load(
        &root.join("scenarios/bicycle_obstacle.toml"),
        &["duration=12.0".to_string()],
    )
    .expect("scenario");
    let path = dir.join("original.mcap");
    let mut episode = Episode::new(&loaded).expect("episode");
    let mut sink = McapSink::create(&path, episode.info(), &[]).expect("create the log");
    let summary = episode.run(&mut [&mut sink]).expect("run");
    assert!(summary.error.is_none(), "{:?}", summary.error);
    std::fs::read(&path).unwrap()
}

/// Top-level records of an MCAP file: (opcode, start, end) with the 9-byte opcode/length
/// prefix included; the magics are (0, …) entries.
fn records(bytes: &[u8]) -> Vec<(u8, usize, usize)> {
    let mut out = vec![(0, 0, 8)];
    let mut pos = 8;
    while pos + 9 <= bytes.len() - 8 {
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        out.push((bytes[pos], pos, pos + 9 + len));
        pos += 9 + len;
    }
    assert_eq!(pos, bytes.len() - 8, "the records end at the end magic");
    out.push((0, pos, bytes.len()));
    out
}

#[derive(Debug, Clone)]
enum Mutation {
    /// Bit `bit` of byte `at`.
    Flip { at: usize, bit: u8 },
    /// `len` random bytes from `at` (each differs from the original).
    Overwrite { at: usize, len: usize, seed: u64 },
    /// The first `len` bytes only.
    Truncate { len: usize },
}

impl Mutation {
    fn apply(&self, original: &[u8]) -> Vec<u8> {
        let mut bytes = original.to_vec();
        match *self {
            Mutation::Flip { at, bit } => bytes[at] ^= 1 << bit,
            Mutation::Overwrite { at, len, seed } => {
                let mut rng = Rng(seed);
                for b in bytes.iter_mut().skip(at).take(len) {
                    *b ^= 1 + (rng.next_u64() % 255) as u8;
                }
            }
            Mutation::Truncate { len } => bytes.truncate(len),
        }
        bytes
    }

    /// Single flips and truncations must be errors (CRC-32 catches every 1-bit error and
    /// every burst of up to 32 bits); an overwrite may in theory collide with a CRC.
    fn must_fail(&self) -> bool {
        !matches!(self, Mutation::Overwrite { len, .. } if *len > 4)
    }
}

/// Case `i`: a bit flip in a uniformly chosen record type (so the few bytes of the header,
/// footer, data end and summary records are hit as often as the chunks), a flip anywhere, a
/// random overwrite, or a truncation.
fn mutation(rng: &mut Rng, records: &[(u8, usize, usize)], size: usize) -> Mutation {
    let mut kinds: Vec<u8> = records.iter().map(|r| r.0).collect();
    kinds.sort_unstable();
    kinds.dedup();
    let in_record = |rng: &mut Rng| {
        let kind = kinds[rng.below(kinds.len())];
        let of_kind: Vec<_> = records.iter().filter(|r| r.0 == kind).collect();
        let (_, start, end) = *of_kind[rng.below(of_kind.len())];
        // The prefix and the first bytes (lengths, ids, sizes) twice as often.
        if rng.below(2) == 0 {
            start + rng.below((end - start).min(48))
        } else {
            start + rng.below(end - start)
        }
    };
    match rng.below(10) {
        0..=4 => Mutation::Flip {
            at: in_record(rng),
            bit: rng.below(8) as u8,
        },
        5 | 6 => Mutation::Flip {
            at: rng.below(size),
            bit: rng.below(8) as u8,
        },
        7 | 8 => {
            let at = in_record(rng);
            Mutation::Overwrite {
                at,
                len: 1 + rng.below(16).min(size - at - 1),
                seed: rng.next_u64(),
            }
        }
        _ => Mutation::Truncate { len: rng.below(size) },
    }
}

fn cases() -> usize {
    std::env::var("MJSAFE_FUZZ_CASES").map_or(3000, |v| v.parse().expect("MJSAFE_FUZZ_CASES: a number"))
}

fn seed() -> u64 {
    std::env::var("MJSAFE_FUZZ_SEED").map_or(1, |v| v.parse().expect("MJSAFE_FUZZ_SEED: a number"))
}

/// Outcome counts by the first words of the error.
fn kind(e: &AnalyzeError) -> &'static str {
    match e {
        AnalyzeError::Read(ReadError::NotMcap { .. }) => "not MCAP",
        AnalyzeError::Corrupt { .. } | AnalyzeError::Read(ReadError::Corrupt { .. }) => "corrupt",
        AnalyzeError::Read(ReadError::Foreign { .. }) => "foreign",
        AnalyzeError::Read(ReadError::Decode { .. }) => "decode",
        AnalyzeError::Read(ReadError::Unordered { .. }) => "unordered",
        AnalyzeError::Read(ReadError::File(_)) => "io",
    }
}

#[test]
fn mutated_logs_are_errors_never_panics_or_wrong_metrics() {
    let dir = tempfile::tempdir().unwrap();
    let original = real_log(dir.path());
    let records = records(&original);
    let chunks = records.iter().filter(|r| r.0 == 0x06).count();
    let expected = analyze::analyze_bytes(&original, "log").expect("the original analyses");
    assert!(expected.complete && expected.collision().is_some(), "{expected:?}");
    assert!(chunks >= 3, "{chunks} chunks");
    let expected = format!("{expected:?}");
    let info = info::log_info(&dir.path().join("original.mcap")).expect("info of the original");

    let (n, seed) = (cases(), seed());
    let mut rng = Rng(seed);
    let mut outcomes: BTreeMap<&str, usize> = BTreeMap::new();
    let mut slowest = Duration::ZERO;
    let started = Instant::now();
    let file = dir.path().join("mutated.mcap");
    for case in 0..n {
        let mutation = mutation(&mut rng, &records, original.len());
        let bytes = mutation.apply(&original);
        let t = Instant::now();
        let result = catch_unwind(AssertUnwindSafe(|| analyze::analyze_bytes(&bytes, "log")));
        slowest = slowest.max(t.elapsed());
        let context = format!("case {case} (seed {seed}): {mutation:?}");
        match result {
            Err(_) => panic!("analyze panicked on {context}"),
            Ok(Ok(m)) => {
                assert!(!mutation.must_fail(), "{context}: a damaged log analysed as valid");
                assert_eq!(format!("{m:?}"), expected, "{context}: wrong metrics reported as valid");
                *outcomes.entry("ok, same metrics").or_default() += 1;
            }
            Ok(Err(e)) => {
                if let AnalyzeError::Corrupt { partial: Some(p), .. } = &e {
                    assert!(!p.complete, "{context}: partial metrics marked complete");
                }
                *outcomes.entry(kind(&e)).or_default() += 1;
            }
        }
        if case % 10 == 0 {
            std::fs::write(&file, &bytes).unwrap();
            match catch_unwind(|| info::log_info(&file)) {
                Err(_) => panic!("info panicked on {context}"),
                Ok(Ok(i)) => {
                    assert!(!mutation.must_fail(), "{context}: info of a damaged log succeeded");
                    assert_eq!(i, info, "{context}");
                }
                Ok(Err(_)) => *outcomes.entry("info: error").or_default() += 1,
            }
        }
    }
    let elapsed = started.elapsed();
    println!(
        "{n} mutations of a {} byte log ({chunks} chunks) in {:.1} s (slowest {:.1} ms): {outcomes:?}",
        original.len(),
        elapsed.as_secs_f64(),
        slowest.as_secs_f64() * 1e3
    );
    assert!(slowest < Duration::from_secs(2), "one case took {slowest:?}");
}

#[test]
fn declared_sizes_beyond_the_file_or_the_limit_are_errors_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let original = real_log(dir.path());
    let &(_, chunk, _) = records(&original).iter().find(|r| r.0 == 0x06).unwrap();
    let compression_len = u32::from_le_bytes(original[chunk + 37..chunk + 41].try_into().unwrap()) as usize;
    // (offset in the chunk record, value): record length, uncompressed size, compressed size.
    let fields = [
        (1, u64::MAX),
        (1, 1 << 40),
        (1, 60 << 20),
        (25, 1 << 40),
        (25, u64::MAX),
        (25, 60 << 20),
    ];
    let compressed = 41 + compression_len;
    for (at, value) in fields
        .into_iter()
        .chain([(compressed, 1 << 40), (compressed, u64::MAX)])
    {
        let mut bytes = original.clone();
        bytes[chunk + at..chunk + at + 8].copy_from_slice(&u64::to_le_bytes(value));
        let started = Instant::now();
        let e = analyze::analyze_bytes(&bytes, "log").expect_err("a damaged chunk");
        println!("chunk field at {at} = {value}: {e}");
        assert!(started.elapsed() < Duration::from_secs(1));
    }
}
