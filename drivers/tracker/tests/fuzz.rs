//! Property-based fuzzing of the Bird record codec (`src/bird.rs`): what the serial line hands
//! the tracker driver goes through [`Decoder::push`] byte by byte, and the protocol has no
//! checksum, so the decoder's behaviour on any byte sequence is specified exactly and checked
//! here against an independent reading of the rules. Whatever the bytes, nothing panics and
//! every record is finite and within full scale; a record that arrives whole is decoded
//! exactly, whatever came before it; encoding and decoding round-trip within quantisation.
//!
//! `cargo test -p softarm-tracker --test fuzz` runs a bounded number of cases, CI more (see
//! docs/FUZZING.md); `PROPTEST_CASES=1000000 cargo test --release -p softarm-tracker --test fuzz`
//! runs longer.

use proptest::prelude::*;
use softarm_tracker::bird::{
    self, Decoder, DecoderStats, MAX_RECORD_BYTES, Record, RecordFormat, decode_record,
    decode_word, encode, encode_word,
};

/// `n` cases, or `PROPTEST_CASES` when set (longer runs by hand, more cases in CI).
fn cases(n: u32) -> ProptestConfig {
    let n = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(n);
    ProptestConfig::with_cases(n)
}

const PHASING: u8 = 0x80;

fn format() -> impl Strategy<Value = RecordFormat> {
    prop_oneof![
        Just(RecordFormat::Position),
        Just(RecordFormat::PositionAngles)
    ]
}

/// The two the device has, and anything else positive the decoder must cope with.
fn full_scale() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(bird::FULL_SCALE_STANDARD_IN),
        Just(bird::FULL_SCALE_EXTENDED_IN),
        1e-3f64..1e4,
    ]
}

/// Bytes off a noisy line: uniformly random (the phasing bit half the time, so whole records
/// are rare), and mostly without the phasing bit (so records, many of them bogus, come often).
fn line_bytes() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        prop::collection::vec(any::<u8>(), 0..600),
        prop::collection::vec(prop_oneof![12 => 0u8..0x80, 1 => 0x80u8..=0xff], 0..600),
    ]
}

/// Feeds `stream` to a fresh decoder: (index of the byte that completed it, record) for every
/// record, and the decoder.
fn run(format: RecordFormat, fs: f64, stream: &[u8]) -> (Vec<(usize, Record)>, Decoder) {
    let mut d = Decoder::new(format, fs);
    let out = stream
        .iter()
        .enumerate()
        .filter_map(|(i, &b)| d.push(b).map(|r| (i, r)))
        .collect();
    (out, d)
}

/// The decoder's documented rules applied another way than its state machine: the stream is
/// cut before every byte with the phasing bit. Bytes before the first cut are dropped. A piece
/// of at least `n` bytes gives a record of its first `n` and drops the rest; a shorter one is
/// malformed, unless it is the last (then it is the record in progress).
fn by_pieces(
    format: RecordFormat,
    fs: f64,
    stream: &[u8],
) -> (Vec<(usize, Record)>, DecoderStats, usize) {
    let n = format.bytes();
    let mut stats = DecoderStats::default();
    let mut records = Vec::new();
    let starts: Vec<usize> = (0..stream.len())
        .filter(|&i| stream[i] & PHASING != 0)
        .collect();
    stats.dropped_bytes = starts.first().copied().unwrap_or(stream.len()) as u64;
    let mut pending = 0;
    for (k, &s) in starts.iter().enumerate() {
        let end = starts.get(k + 1).copied().unwrap_or(stream.len());
        let len = end - s;
        if len >= n {
            let r = decode_record(format, fs, &stream[s..s + n]).expect("a whole piece decodes");
            records.push((s + n - 1, r));
            stats.records += 1;
            stats.dropped_bytes += (len - n) as u64;
        } else if k + 1 == starts.len() {
            pending = len;
        } else {
            stats.malformed += 1;
        }
    }
    (records, stats, pending)
}

/// What every record handed to the driver must satisfy, whatever the bytes were.
fn assert_sane(r: &Record, format: RecordFormat, fs: f64) -> Result<(), TestCaseError> {
    for p in r.position_in {
        prop_assert!(p.is_finite() && p.abs() <= fs, "position {p} beyond ±{fs}");
    }
    match (format, r.angles_deg) {
        (RecordFormat::Position, None) => {}
        (RecordFormat::PositionAngles, Some(a)) => {
            for x in a {
                prop_assert!((-180.0..180.0).contains(&x), "angle {x}");
            }
        }
        (f, a) => prop_assert!(false, "{f:?} record with angles {a:?}"),
    }
    Ok(())
}

/// The smallest difference of two angles on the circle, degrees.
fn angle_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(360.0);
    d.min(360.0 - d)
}

/// One record's bytes as the device sends them: any 14-bit words, the phasing bit on the first.
fn valid_record(format: RecordFormat) -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(0u8..0x80, format.bytes()).prop_map(|mut b| {
        b[0] |= PHASING;
        b
    })
}

/// What can happen to a record on the line.
#[derive(Clone, Debug)]
enum Damage {
    None,
    /// A byte inserted before byte `at` (of the record's).
    Insert(usize, u8),
    /// Byte `at` lost.
    Lose(usize),
    /// Byte `at` changed (xor with a non-zero mask).
    Flip(usize, u8),
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        4 => Just(Damage::None),
        1 => (1usize..MAX_RECORD_BYTES, any::<u8>()).prop_map(|(at, b)| Damage::Insert(at, b)),
        1 => (0usize..MAX_RECORD_BYTES).prop_map(Damage::Lose),
        1 => (0usize..MAX_RECORD_BYTES, 1u8..=0xff).prop_map(|(at, m)| Damage::Flip(at, m)),
    ]
}

/// Garbage between records: none, bytes without the phasing bit only, or anything.
fn garbage() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        3 => Just(Vec::new()),
        1 => prop::collection::vec(0u8..0x80, 1..30),
        1 => prop::collection::vec(any::<u8>(), 1..30),
    ]
}

/// Garbage before a record, the record as sent, what happens to it.
type Piece = (Vec<u8>, Vec<u8>, Damage);

/// A stream of records in `format`, each preceded by garbage and possibly damaged.
fn noisy_records() -> impl Strategy<Value = (RecordFormat, Vec<Piece>)> {
    format().prop_flat_map(|f| {
        (
            Just(f),
            prop::collection::vec((garbage(), valid_record(f), damage()), 0..40),
        )
    })
}

proptest! {
    #![proptest_config(cases(2048))]

    /// Any bytes: no panic; the records, the counts and the bytes left pending are exactly
    /// what the documented rules give; every record is finite and within full scale.
    #[test]
    fn any_bytes_decode_exactly_as_documented(
        format in format(),
        fs in full_scale(),
        stream in line_bytes(),
    ) {
        let (got, d) = run(format, fs, &stream);
        let (want, stats, pending) = by_pieces(format, fs, &stream);
        prop_assert_eq!(&got, &want);
        prop_assert_eq!(d.stats(), stats);
        prop_assert_eq!(d.pending(), pending);
        prop_assert!(d.pending() < format.bytes());
        for (_, r) in &got {
            assert_sane(r, format, fs)?;
        }
        // Every byte is accounted for once: dropped, in a record, in the one in progress, or
        // in a malformed partial (each of those at least one byte, at most n - 1).
        let n = format.bytes() as u64;
        let s = d.stats();
        let placed = s.dropped_bytes + s.records * n + d.pending() as u64;
        let rest = stream.len() as u64 - placed;
        prop_assert!(s.malformed <= rest && rest <= s.malformed * (n - 1));
    }

    /// The phasing bit's guarantee: a record whose bytes arrive contiguously and unaltered is
    /// decoded exactly, at its last byte, whatever came before it (garbage, a partial record,
    /// a damaged one). Every record the decoder emits is made of the `n` bytes up to the byte
    /// that completed it, the first with the phasing bit and no other. On a clean line every
    /// record comes out and nothing else; with garbage free of the phasing bit between
    /// records, still exactly the records.
    #[test]
    fn records_untouched_by_garbage_come_through(
        (format, pieces) in noisy_records(),
        fs in full_scale(),
    ) {
        let n = format.bytes();
        let mut stream = Vec::new();
        // (index of its last byte, its bytes) of every record that arrived whole.
        let mut intact = Vec::new();
        let mut clean = true;
        let mut phased_garbage = false;
        for (junk, record, damage) in &pieces {
            stream.extend_from_slice(junk);
            phased_garbage |= junk.iter().any(|b| b & PHASING != 0);
            let mut r = record.clone();
            match *damage {
                Damage::None => {}
                Damage::Insert(at, b) => r.insert(at.min(n - 1), b),
                Damage::Lose(at) => {
                    r.remove(at % n);
                }
                Damage::Flip(at, mask) => r[at % n] ^= mask,
            }
            if r == *record {
                intact.push((stream.len() + n - 1, r.clone()));
            } else {
                clean = false;
            }
            stream.extend_from_slice(&r);
        }
        let (got, d) = run(format, fs, &stream);
        for &(end, ref bytes) in &intact {
            let want = decode_record(format, fs, bytes).unwrap();
            let at = got.iter().find(|(i, _)| *i == end).map(|(_, r)| *r);
            prop_assert_eq!(at, Some(want), "record ending at byte {} lost", end);
        }
        for &(end, r) in &got {
            prop_assert!(end + 1 >= n);
            let window = &stream[end + 1 - n..=end];
            prop_assert_eq!(Some(r), decode_record(format, fs, window));
            assert_sane(&r, format, fs)?;
        }
        if clean && !phased_garbage {
            let want: Vec<Record> =
                intact.iter().map(|(_, b)| decode_record(format, fs, b).unwrap()).collect();
            let have: Vec<Record> = got.iter().map(|(_, r)| *r).collect();
            prop_assert_eq!(have, want);
            prop_assert_eq!(d.stats().malformed, 0);
            let junk: usize = pieces.iter().map(|(j, _, _)| j.len()).sum();
            prop_assert_eq!(d.stats().dropped_bytes, junk as u64);
            prop_assert_eq!(d.pending(), 0);
        }
    }

    /// `decode_record` on any bytes: a record exactly when the length and the phasing bits
    /// are right, and then the same record the stream decoder makes of those bytes.
    #[test]
    fn decode_record_accepts_exactly_whole_records(
        format in format(),
        fs in full_scale(),
        bytes in prop::collection::vec(any::<u8>(), 0..2 * MAX_RECORD_BYTES),
    ) {
        let r = decode_record(format, fs, &bytes);
        let whole = bytes.len() == format.bytes()
            && bytes[0] & PHASING != 0
            && bytes[1..].iter().all(|b| b & PHASING == 0);
        prop_assert_eq!(r.is_some(), whole);
        if let Some(r) = r {
            assert_sane(&r, format, fs)?;
            let (got, _) = run(format, fs, &bytes);
            prop_assert_eq!(got, vec![(bytes.len() - 1, r)]);
        }
    }

    /// A word's two bytes: bit 7 of each is not data, the two lowest bits of the value are 0,
    /// and encoding gives back the data bits.
    #[test]
    fn words_round_trip(ls in any::<u8>(), ms in any::<u8>(), v in any::<i16>()) {
        let w = decode_word(ls, ms);
        prop_assert_eq!(w & 3, 0);
        prop_assert_eq!(decode_word(ls & 0x7f, ms & 0x7f), w);
        prop_assert_eq!(encode_word(w), [ls & 0x7f, ms & 0x7f]);
        prop_assert_eq!(decode_word(encode_word(v)[0], encode_word(v)[1]), v & !3);
        prop_assert!(encode_word(v).iter().all(|b| b & PHASING == 0));
    }

    /// decode(encode(r)) is r within half a step: positions clamped to the representable
    /// range [-full scale, full scale - 1 step] first, angles on the circle, NaN as 0; and a
    /// decoded record encodes to the same bytes again.
    #[test]
    fn encode_then_decode_is_within_quantisation(
        format in format(),
        fs in full_scale(),
        position in prop::array::uniform3(prop_oneof![
            6 => -1.2f64..1.2,
            1 => Just(f64::NAN),
            1 => Just(f64::INFINITY),
            1 => Just(f64::NEG_INFINITY),
            1 => any::<f64>(),
            1 => Just(1.0),
            1 => Just(-1.0),
        ]),
        angles in prop::option::of(prop::array::uniform3(prop_oneof![
            6 => -720.0f64..720.0,
            1 => Just(f64::NAN),
            1 => Just(f64::INFINITY),
            1 => any::<f64>(),
            1 => Just(180.0),
            1 => Just(-180.0),
        ])),
    ) {
        // Positions as fractions of full scale (so every full scale sees its whole range).
        let record = Record { position_in: position.map(|p| p * fs), angles_deg: angles };
        let n = format.bytes();
        let mut out = [0x55u8; MAX_RECORD_BYTES + 1];
        prop_assert_eq!(encode(format, fs, &record, &mut out), n);
        prop_assert!(out[n..].iter().all(|&b| b == 0x55), "wrote past the record");
        let got = decode_record(format, fs, &out[..n]);
        prop_assert!(got.is_some(), "{:02x?}", &out[..n]);
        let got = got.unwrap();
        assert_sane(&got, format, fs)?;

        let step = fs / 8192.0;
        let top = fs - step;
        for (x, y) in record.position_in.iter().zip(got.position_in) {
            if x.is_nan() {
                prop_assert_eq!(y, 0.0);
            } else {
                let want = x.clamp(-fs, top);
                prop_assert!((y - want).abs() <= 0.5 * step * (1.0 + 1e-9), "{x} -> {y}");
            }
        }
        if format == RecordFormat::PositionAngles {
            let step = 180.0 / 8192.0;
            let want = record.angles_deg.unwrap_or([0.0; 3]);
            for (&a, y) in want.iter().zip(got.angles_deg.unwrap()) {
                if !a.is_finite() {
                    prop_assert_eq!(y, 0.0);
                } else if a.abs() < 1e9 {
                    prop_assert!(angle_diff(y, a) <= 0.5 * step + 1e-6, "{a} -> {y}");
                }
            }
        }

        let mut again = [0u8; MAX_RECORD_BYTES];
        encode(format, fs, &got, &mut again);
        prop_assert_eq!(&again[..n], &out[..n], "quantisation is not a fixed point");
    }
}

/// The other pure functions of the module, over all their inputs.
#[test]
fn command_and_parameter_tables_answer_every_byte() {
    for c in 0..=u8::MAX {
        match RecordFormat::from_command(c) {
            Some(f) => {
                assert_eq!(f.command(), c);
                assert_eq!(f.bytes(), 2 * f.words());
                assert!(f.bytes() <= MAX_RECORD_BYTES);
            }
            None => assert!(c != bird::POSITION && c != bird::POSITION_ANGLES),
        }
        let examine = bird::examine_value_len(c);
        assert!(
            examine.is_none_or(|n| (1..=14).contains(&n)),
            "{c}: {examine:?}"
        );
        let change = bird::change_value_len(c);
        match c {
            bird::param::FLOCK_SYSTEM_STATUS => assert_eq!(change, None),
            bird::param::FBB_AUTO_CONFIG => assert_eq!(change, Some(1)),
            _ => assert_eq!(change, examine, "{c}"),
        }
    }
}
