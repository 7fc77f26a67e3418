//! The Ascension Bird RS-232 binary protocol, as spoken by Flock of Birds, pciBIRD and
//! trakSTAR-class electromagnetic trackers: command bytes, the record layout, a decoder that
//! finds record boundaries by the phasing bit, and the matching encoder (used by the emulator).
//! Pure: no I/O, and the decoder does not allocate.
//!
//! # Where the facts come from
//!
//! - Ascension Technology Corp., *Flock of Birds Installation and Operation Guide*, chapter "RS232
//!   Commands": the command bytes (POINT `B`, STREAM `@`, POSITION `V`, POSITION/ANGLES `Y`, RUN
//!   `F`, SLEEP `G`, EXAMINE VALUE `O`, CHANGE VALUE `P`, HEMISPHERE `L`, RS232 TO FBB `0xF0 +
//!   address`), the record tables (each word sent LS byte first; bit 7 of the first byte of a
//!   record is the phasing bit, 1, and bit 7 of every other byte is 0; the LS byte carries data
//!   bits 2..8, the MS byte bits 9..15), the scaling of positions (signed full scale of 36 in,
//!   72 in with the POSITION SCALING parameter set to 1) and of angles (full scale 180°), and the
//!   order of the angles in a record (Z = azimuth, Y = elevation, X = roll).
//! - Ascension Technology Corp., *3D Guidance trakSTAR Installation and Operation Guide*, RS-232
//!   command set, which keeps the Flock commands above and adds STREAM STOP `?`.
//! - Cross-checked against open-source host drivers that decode the same records: libflock
//!   (SCRIME, Université Bordeaux 1), the Atamai "Flock of Birds C Interface Library" and its
//!   descendant in IGSTK (`AscensionCommandInterpreter`), and Vrui's VRDeviceDaemon
//!   `AscensionFlockOfBirds`. All of them unpack a word as
//!   `(((ms & 0x7f) << 7 | (ls & 0x7f)) << 2) as i16` and scale it by `1/32768` of the full
//!   scale; they also give the EXAMINE/CHANGE VALUE parameter numbers and data lengths below.
//!   STREAM STOP could not be confirmed in any of these (they predate the trakSTAR and stop a
//!   stream with POINT, which every Bird accepts); it is kept as the trakSTAR guide names it.
//!
//! # The hemisphere
//!
//! The transmitter's field is the same at p and -p, so a Bird cannot tell which side of its
//! centre a sensor is on: it reports every position in the selected hemisphere (default
//! FORWARD, +X), and a sensor beyond the boundary plane comes out with X, Y and Z all negated.
//! The angles are left as they are: the field vectors the sensor measures are the same at both
//! points, so the orientation computed from them is too. (Polhemus, *FASTRAK Manual* rev. G,
//! "H – Hemisphere of Operation", says the same of its AC trackers: "an ambiguity (usually sign
//! flips) in the X, Y, Z measurements"; the Flock guide's chapter on HEMISPHERE could not be
//! consulted here, so this reading rests on that and on the symmetry of a dipole field.)
//!
//! HEMISPHERE is `L` followed by two bytes, HEMI AXIS then HEMI SIGN ([`Hemisphere::bytes`]):
//!
//! ```text
//! FORWARD  0x00 0x00    +X        AFT    0x00 0x01    -X
//! LOWER    0x0C 0x00    +Z        UPPER  0x0C 0x01    -Z   (Z points down on a Bird)
//! RIGHT    0x06 0x00    +Y        LEFT   0x06 0x01    -Y
//! ```
//!
//! Source: IGSTK `igstkAscensionCommandInterpreter.h` (from the Atamai Flock of Birds C
//! interface), `enum AscensionHemisphere`: `FB_FORWARD = 0x0000, FB_AFT = 0x0100, FB_UPPER =
//! 0x010C, FB_LOWER = 0x000C, FB_LEFT = 0x0106, FB_RIGHT = 0x0006`, sent after `L` with
//! `SendCommandWords`, i.e. as a 16-bit word LS byte first: the axis byte, then the sign byte.
//! The same header gives the parameter of EXAMINE/CHANGE VALUE, `FB_P_HEMISPHERE = 22`
//! ([`param::HEMISPHERE`]), whose value is that same word: EXAMINE VALUE `O 22` is answered with
//! two plain bytes, axis then sign. IGSTK's own test notes that "the FB_P_HEMISPHERE is not
//! available on old bird units" (software revision below 3.66), so a missing answer is not an
//! error (the driver logs it once and goes on).
//!
//! # Record layout
//!
//! A record is `words` 16-bit words, each sent as two bytes, LS byte first. Each word carries 14
//! significant bits (the two lowest bits of the 16-bit two's-complement value are always 0):
//!
//! ```text
//!            bit 7   bits 6..0
//! LS byte    P       D8 D7 D6 D5 D4 D3 D2     P = 1 on the first byte of a record, else 0
//! MS byte    0       D15 D14 ... D9
//! value      (((ms & 0x7f) << 7 | (ls & 0x7f)) << 2) as i16
//! ```
//!
//! Positions are `value / 32768 × full scale` inches, angles `value / 32768 × 180` degrees. The
//! protocol has no checksum: a record of the right length is all the decoder can check.

/// POINT: the Bird sends one record in the current format. Also ends STREAM mode.
pub const POINT: u8 = b'B';
/// STREAM: the Bird sends records continuously, at its measurement rate, until POINT (or STREAM
/// STOP on a trakSTAR) arrives.
pub const STREAM: u8 = b'@';
/// STREAM STOP (trakSTAR): ends STREAM mode without asking for a record.
pub const STREAM_STOP: u8 = b'?';
/// POSITION: records carry X, Y, Z (3 words, 6 bytes).
pub const POSITION: u8 = b'V';
/// POSITION/ANGLES: records carry X, Y, Z, then the Z angle (azimuth), the Y angle (elevation)
/// and the X angle (roll) (6 words, 12 bytes).
pub const POSITION_ANGLES: u8 = b'Y';
/// RUN: wakes the Bird from SLEEP (transmitter on, measurements resume).
pub const RUN: u8 = b'F';
/// SLEEP: turns the transmitter off; no records until RUN.
pub const SLEEP: u8 = b'G';
/// EXAMINE VALUE: followed by one parameter byte (see [`param`]); the Bird answers with the
/// parameter's value as plain bytes (no phasing bit), LS byte first for words.
pub const EXAMINE_VALUE: u8 = b'O';
/// CHANGE VALUE: followed by one parameter byte (see [`param`]) and
/// [`change_value_len`]`(parameter)` data bytes, LS byte first for words. No answer.
pub const CHANGE_VALUE: u8 = b'P';
/// HEMISPHERE: followed by two data bytes (axis, sign). No answer.
pub const HEMISPHERE: u8 = b'L';
/// RS232 TO FBB, normal addressing: `RS232_TO_FBB | address` (address 1..=15) prefixes a command
/// meant for one Bird of a flock. A single stand-alone unit accepts and ignores it.
pub const RS232_TO_FBB: u8 = 0xF0;

/// The number of bytes in the longest record this module handles (POSITION/ANGLES).
pub const MAX_RECORD_BYTES: usize = 12;
/// Default signed full scale of positions, inches.
pub const FULL_SCALE_STANDARD_IN: f64 = 36.0;
/// Full scale of positions with the POSITION SCALING parameter set to 1, inches.
pub const FULL_SCALE_EXTENDED_IN: f64 = 72.0;
/// Full scale of angles, degrees.
pub const ANGLE_FULL_SCALE_DEG: f64 = 180.0;

/// The bit that marks the first byte of a record.
const PHASING_BIT: u8 = 0x80;
/// `32768 / 4`: the number of 14-bit steps in one signed full scale.
const STEPS: f64 = 8192.0;

/// Parameter numbers of EXAMINE VALUE and CHANGE VALUE.
pub mod param {
    /// Bird status word (2 bytes, see [`super::status`]). Examine only.
    pub const BIRD_STATUS: u8 = 0;
    /// Software revision (2 bytes: integer part, fraction). Examine only.
    pub const SOFTWARE_REVISION: u8 = 1;
    /// Position scaling (2 bytes): 0 = 36 in full scale, 1 = 72 in.
    pub const POSITION_SCALING: u8 = 3;
    /// Measurement rate (2 bytes).
    pub const MEASUREMENT_RATE: u8 = 7;
    /// Hemisphere (2 bytes: axis, sign, as after the HEMISPHERE command; see
    /// [`super::Hemisphere`]). Units before software revision 3.66 do not answer it.
    pub const HEMISPHERE: u8 = 22;
    /// Group mode (1 byte): when 1, every record gets the Bird's address byte appended. Not
    /// supported by [`super::Decoder`].
    pub const GROUP_MODE: u8 = 35;
    /// Flock system status (14 bytes in normal addressing mode). Examine only.
    pub const FLOCK_SYSTEM_STATUS: u8 = 36;
    /// FBB auto-configuration (1 data byte: the number of Birds).
    pub const FBB_AUTO_CONFIG: u8 = 50;
}

/// Bits of the BIRD STATUS word ([`param::BIRD_STATUS`]).
pub mod status {
    /// The Bird is in STREAM mode.
    pub const STREAMING: u16 = 0x0001;
    /// Output format field: `(format command - POSITION + 1) << 1`.
    pub const FORMAT_MASK: u16 = 0x001E;
    /// The Bird is asleep (SLEEP).
    pub const SLEEPING: u16 = 0x0020;
    /// The Bird is running (RUN).
    pub const RUNNING: u16 = 0x1000;
    /// An error is pending.
    pub const ERROR: u16 = 0x2000;
    /// The Bird is initialized.
    pub const INITIALIZED: u16 = 0x4000;
    /// The Bird is the master of its flock (a stand-alone unit is).
    pub const MASTER: u16 = 0x8000;
}

/// The number of data bytes that follow the parameter byte of a CHANGE VALUE command, or `None`
/// for a parameter this table does not know (or that cannot be changed).
pub fn change_value_len(parameter: u8) -> Option<usize> {
    match parameter {
        param::FLOCK_SYSTEM_STATUS => None,
        param::FBB_AUTO_CONFIG => Some(1),
        p => examine_value_len(p),
    }
}

/// The number of bytes a Bird answers to EXAMINE VALUE of `parameter` (normal addressing mode),
/// or `None` for a parameter this table does not know.
pub fn examine_value_len(parameter: u8) -> Option<usize> {
    Some(match parameter {
        0..=4 => 2,
        5 => 14,
        6 | 7 => 2,
        8..=11 => 1,
        12 | 13 => 14,
        14 => 1,
        15 => 10,
        16 => 2,
        17..=21 => 1,
        22 => 2,
        23 | 24 => 6,
        25..=27 => 2,
        32 => 2,
        param::GROUP_MODE => 1,
        param::FLOCK_SYSTEM_STATUS => 14,
        param::FBB_AUTO_CONFIG => 5,
        _ => return None,
    })
}

/// The hemisphere a Bird reports positions in (see the module docs): the config's type, one
/// meaning in one place; its bytes on the wire are [`HemisphereBytes`].
pub use softarm_config::hardware::TrackerHemisphere as Hemisphere;

/// A hemisphere as the protocol spells it.
pub trait HemisphereBytes: Sized {
    /// HEMI AXIS, HEMI SIGN: the two bytes after [`HEMISPHERE`], and the answer to EXAMINE
    /// VALUE of [`param::HEMISPHERE`].
    fn bytes(self) -> [u8; 2];
    /// The hemisphere two bytes name, if they name one.
    fn from_bytes(bytes: [u8; 2]) -> Option<Self>;
    /// The whole command: [`HEMISPHERE`], axis, sign.
    fn command(self) -> [u8; 3];
}

impl HemisphereBytes for Hemisphere {
    fn bytes(self) -> [u8; 2] {
        match self {
            Self::Forward => [0x00, 0x00],
            Self::Aft => [0x00, 0x01],
            Self::Upper => [0x0C, 0x01],
            Self::Lower => [0x0C, 0x00],
            Self::Left => [0x06, 0x01],
            Self::Right => [0x06, 0x00],
        }
    }

    fn from_bytes(bytes: [u8; 2]) -> Option<Self> {
        Self::ALL.into_iter().find(|h| h.bytes() == bytes)
    }

    fn command(self) -> [u8; 3] {
        let [axis, sign] = self.bytes();
        [HEMISPHERE, axis, sign]
    }
}

/// The record formats this module decodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecordFormat {
    /// X, Y, Z.
    Position,
    /// X, Y, Z, Z angle (azimuth), Y angle (elevation), X angle (roll).
    PositionAngles,
}

impl RecordFormat {
    /// The command byte that selects this format.
    pub fn command(self) -> u8 {
        match self {
            Self::Position => POSITION,
            Self::PositionAngles => POSITION_ANGLES,
        }
    }

    /// The format a command byte selects, if it is one of [`POSITION`], [`POSITION_ANGLES`].
    pub fn from_command(command: u8) -> Option<Self> {
        match command {
            POSITION => Some(Self::Position),
            POSITION_ANGLES => Some(Self::PositionAngles),
            _ => None,
        }
    }

    /// 16-bit words in one record.
    pub fn words(self) -> usize {
        match self {
            Self::Position => 3,
            Self::PositionAngles => 6,
        }
    }

    /// Bytes in one record on the wire.
    pub fn bytes(self) -> usize {
        2 * self.words()
    }
}

/// One decoded record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Record {
    /// X, Y, Z of the sensor in the transmitter frame, inches.
    pub position_in: [f64; 3],
    /// In the record's order: Z angle (azimuth), Y angle (elevation), X angle (roll), degrees in
    /// [-180, 180). `None` for [`RecordFormat::Position`].
    pub angles_deg: Option<[f64; 3]>,
}

/// Counts since the decoder was made.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Complete records decoded.
    pub records: u64,
    /// Partial records abandoned because a byte with the phasing bit came too early.
    pub malformed: u64,
    /// Bytes without the phasing bit that came while no record had started.
    pub dropped_bytes: u64,
    /// Complete records not handed out because [`Decoder::discard_next`] asked (also counted in
    /// `records`).
    pub discarded: u64,
}

/// The 16-bit two's-complement value of a word from its two bytes as sent (bit 7 of each byte,
/// the phasing bit or 0, is ignored). The two lowest bits are always 0.
pub fn decode_word(ls: u8, ms: u8) -> i16 {
    let bits14 = (u16::from(ms & 0x7f) << 7) | u16::from(ls & 0x7f);
    (bits14 << 2) as i16
}

/// The two bytes (LS first, bit 7 of both 0) that carry `value`; its two lowest bits are lost.
pub fn encode_word(value: i16) -> [u8; 2] {
    let bits14 = (value as u16) >> 2;
    [(bits14 & 0x7f) as u8, ((bits14 >> 7) & 0x7f) as u8]
}

/// Decodes one whole record: `bytes` must be exactly `format.bytes()` long, start with the
/// phasing bit and have it clear everywhere else; otherwise `None`.
pub fn decode_record(format: RecordFormat, full_scale_in: f64, bytes: &[u8]) -> Option<Record> {
    if bytes.len() != format.bytes()
        || bytes[0] & PHASING_BIT == 0
        || bytes[1..].iter().any(|b| b & PHASING_BIT != 0)
    {
        return None;
    }
    Some(decode_unchecked(format, full_scale_in, bytes))
}

/// Decodes a record whose length is known to be right.
fn decode_unchecked(format: RecordFormat, full_scale_in: f64, bytes: &[u8]) -> Record {
    let value = |i: usize| f64::from(decode_word(bytes[2 * i], bytes[2 * i + 1])) / 32768.0;
    let position_in = [0, 1, 2].map(|i| value(i) * full_scale_in);
    let angles_deg = match format {
        RecordFormat::Position => None,
        RecordFormat::PositionAngles => Some([3, 4, 5].map(|i| value(i) * ANGLE_FULL_SCALE_DEG)),
    };
    Record {
        position_in,
        angles_deg,
    }
}

/// Finds record boundaries by the phasing bit in a byte stream that may start mid-record,
/// lose bytes or carry garbage.
///
/// A byte with the phasing bit always starts a new record (a partial record before it counts as
/// malformed); bytes without it while no record has started are dropped; a record is emitted as
/// soon as it has `format.bytes()` bytes. Fixed-size state, no allocation, never panics on any
/// byte sequence.
#[derive(Clone, Debug)]
pub struct Decoder {
    format: RecordFormat,
    full_scale_in: f64,
    buf: [u8; MAX_RECORD_BYTES],
    len: usize,
    stats: DecoderStats,
    /// Complete records still to be swallowed (see [`Decoder::discard_next`]).
    discard: u32,
}

impl Decoder {
    /// A decoder of `format` records whose positions have a full scale of `full_scale_in` inches
    /// ([`FULL_SCALE_STANDARD_IN`] unless POSITION SCALING was changed).
    ///
    /// # Panics
    ///
    /// If `full_scale_in` is not a finite positive number.
    pub fn new(format: RecordFormat, full_scale_in: f64) -> Self {
        assert!(
            full_scale_in.is_finite() && full_scale_in > 0.0,
            "full scale must be a finite positive number of inches, got {full_scale_in}"
        );
        Self {
            format,
            full_scale_in,
            buf: [0; MAX_RECORD_BYTES],
            len: 0,
            stats: DecoderStats::default(),
            discard: 0,
        }
    }

    /// The format this decoder expects.
    pub fn format(&self) -> RecordFormat {
        self.format
    }

    /// The position full scale, inches.
    pub fn full_scale_in(&self) -> f64 {
        self.full_scale_in
    }

    /// Feeds one byte; returns a record when this byte completes one.
    pub fn push(&mut self, byte: u8) -> Option<Record> {
        if byte & PHASING_BIT != 0 {
            if self.len > 0 {
                self.stats.malformed += 1;
            }
            self.buf[0] = byte;
            self.len = 1;
        } else if self.len == 0 {
            self.stats.dropped_bytes += 1;
            return None;
        } else {
            self.buf[self.len] = byte;
            self.len += 1;
        }
        let n = self.format.bytes();
        if self.len < n {
            return None;
        }
        self.len = 0;
        self.stats.records += 1;
        if self.discard > 0 {
            self.discard -= 1;
            self.stats.discarded += 1;
            return None;
        }
        Some(decode_unchecked(
            self.format,
            self.full_scale_in,
            &self.buf[..n],
        ))
    }

    /// Counts since the decoder was made.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Bytes of the record in progress (0 when between records).
    pub fn pending(&self) -> usize {
        self.len
    }

    /// Swallow the next `n` complete records (replacing any count still pending): the record a
    /// Bird sends when POINT ends its stream answers the stop, not a question about the pose
    /// now, and must not come out as a fresh sample. Malformed partials do not use it up.
    pub fn discard_next(&mut self, n: u32) {
        self.discard = n;
    }

    /// Complete records still to be swallowed.
    pub fn discard_pending(&self) -> u32 {
        self.discard
    }

    /// Forget a partial record (e.g. after the port was reopened); does not count it malformed.
    /// A pending [`Decoder::discard_next`] stays.
    pub fn reset(&mut self) {
        self.len = 0;
    }
}

/// The 14-bit step count of `x` on a signed full scale `full`, rounded to nearest and saturated
/// to the representable range [-8192, 8191]; NaN gives 0.
fn to_steps(x: f64, full: f64) -> i16 {
    (x / full * STEPS).round().clamp(-STEPS, STEPS - 1.0) as i16
}

/// The 14-bit step count of an angle, wrapped into [-180°, 180°) as the device reports angles
/// (so 190° goes out as -170°, and 180° as -180°); NaN or infinite gives 0.
fn angle_steps(deg: f64) -> i16 {
    if !deg.is_finite() {
        return 0;
    }
    let steps = (deg / ANGLE_FULL_SCALE_DEG * STEPS).round();
    (steps + STEPS).rem_euclid(2.0 * STEPS) as i16 - STEPS as i16
}

/// Encodes a record as the device sends it (phasing bit on the first byte).
///
/// Positions are rounded to the nearest step (`full_scale_in / 8192`) and saturate to the
/// largest representable word beyond ±full scale (+full scale itself goes out as the largest
/// word, one step below it). Angles are rounded to the nearest step (180° / 8192) and wrapped
/// into [-180°, 180°), as the device reports them, instead of saturating. A
/// [`RecordFormat::PositionAngles`] record without angles sends zero angles; a
/// [`RecordFormat::Position`] record ignores them. NaN goes out as 0.
///
/// Returns the number of bytes written to `out` (`format.bytes()`).
///
/// # Panics
///
/// If `out` is shorter than `format.bytes()` ([`MAX_RECORD_BYTES`] always suffices).
pub fn encode(format: RecordFormat, full_scale_in: f64, record: &Record, out: &mut [u8]) -> usize {
    let n = format.bytes();
    let out = &mut out[..n];
    let mut steps = [0i16; 6];
    for i in 0..3 {
        steps[i] = to_steps(record.position_in[i], full_scale_in);
    }
    if format == RecordFormat::PositionAngles {
        let angles = record.angles_deg.unwrap_or([0.0; 3]);
        for i in 0..3 {
            steps[3 + i] = angle_steps(angles[i]);
        }
    }
    for i in 0..format.words() {
        // Steps are within [-8192, 8191], so the shift cannot overflow.
        let [ls, ms] = encode_word(steps[i] << 2);
        out[2 * i] = ls;
        out[2 * i + 1] = ms;
    }
    out[0] |= PHASING_BIT;
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    const FS: f64 = 36.0;
    const POS_LSB: f64 = FS / 8192.0;
    const ANG_LSB: f64 = 180.0 / 8192.0;

    fn rec(p: [f64; 3], a: [f64; 3]) -> Record {
        Record {
            position_in: p,
            angles_deg: Some(a),
        }
    }

    fn feed(d: &mut Decoder, bytes: &[u8]) -> Vec<Record> {
        bytes.iter().filter_map(|&b| d.push(b)).collect()
    }

    /// Difference of two angles on the circle, degrees.
    fn angle_diff(a: f64, b: f64) -> f64 {
        let d = (a - b).rem_euclid(360.0);
        d.min(360.0 - d)
    }

    #[test]
    fn commands_are_the_documented_bytes() {
        assert_eq!(POINT, 0x42);
        assert_eq!(STREAM, 0x40);
        assert_eq!(STREAM_STOP, 0x3f);
        assert_eq!(POSITION, 0x56);
        assert_eq!(POSITION_ANGLES, 0x59);
        assert_eq!(RUN, 0x46);
        assert_eq!(SLEEP, 0x47);
        assert_eq!(EXAMINE_VALUE, 0x4f);
        assert_eq!(CHANGE_VALUE, 0x50);
        assert_eq!(RecordFormat::Position.command(), POSITION);
        assert_eq!(RecordFormat::PositionAngles.command(), POSITION_ANGLES);
        assert_eq!(RecordFormat::Position.bytes(), 6);
        assert_eq!(RecordFormat::PositionAngles.bytes(), 12);
        assert_eq!(RecordFormat::PositionAngles.words(), 6);
        assert_eq!(
            RecordFormat::from_command(b'Y'),
            Some(RecordFormat::PositionAngles)
        );
        assert_eq!(RecordFormat::from_command(b'W'), None);
        assert_eq!(change_value_len(param::POSITION_SCALING), Some(2));
        assert_eq!(change_value_len(param::GROUP_MODE), Some(1));
        assert_eq!(change_value_len(param::FBB_AUTO_CONFIG), Some(1));
        assert_eq!(change_value_len(200), None);
    }

    #[test]
    fn hemisphere_bytes_are_the_documented_ones() {
        // IGSTK's AscensionHemisphere words, LS byte (axis) first.
        let table = [
            (Hemisphere::Forward, 0x0000u16),
            (Hemisphere::Aft, 0x0100),
            (Hemisphere::Upper, 0x010C),
            (Hemisphere::Lower, 0x000C),
            (Hemisphere::Left, 0x0106),
            (Hemisphere::Right, 0x0006),
        ];
        for (h, word) in table {
            assert_eq!(h.bytes(), word.to_le_bytes(), "{h:?}");
            assert_eq!(h.command(), [b'L', word as u8, (word >> 8) as u8], "{h:?}");
            assert_eq!(Hemisphere::from_bytes(h.bytes()), Some(h));
        }
        assert_eq!(HEMISPHERE, 0x4c);
        assert_eq!(param::HEMISPHERE, 22);
        assert_eq!(examine_value_len(param::HEMISPHERE), Some(2));
        assert_eq!(change_value_len(param::HEMISPHERE), Some(2));
        // Anything else is not a hemisphere (a garbled read-back, a stray record byte).
        for bytes in [
            [0x00, 0x02],
            [0x01, 0x00],
            [0x0C, 0x80],
            [0x80, 0x00],
            [0x12, 0x00],
        ] {
            assert_eq!(Hemisphere::from_bytes(bytes), None, "{bytes:?}");
        }
    }

    #[test]
    fn the_record_after_point_is_discarded_not_handed_out() {
        let (bytes, want) = three_records();
        let mut d = Decoder::new(RecordFormat::PositionAngles, FS);
        // Half a streamed record is in the line when POINT ends the stream; its answer follows.
        assert!(feed(&mut d, &bytes[..5]).is_empty());
        d.discard_next(1);
        assert_eq!(d.discard_pending(), 1);
        // The partial record and the POINT answer: neither comes out, only the answer counts
        // as discarded (the partial as malformed).
        assert!(feed(&mut d, &bytes[12..24]).is_empty());
        assert_eq!(d.discard_pending(), 0);
        // The next record is a fresh one again.
        assert_eq!(feed(&mut d, &bytes[24..]), want[2..]);
        assert_eq!(
            d.stats(),
            DecoderStats {
                records: 2,
                malformed: 1,
                dropped_bytes: 0,
                discarded: 1,
            }
        );
        // A reset (a reopened port) keeps a discard that is still owed; 0 cancels it.
        d.discard_next(2);
        d.reset();
        assert!(feed(&mut d, &bytes[..24]).is_empty());
        assert_eq!(feed(&mut d, &bytes[..12]), want[..1]);
        d.discard_next(1);
        d.discard_next(0);
        assert_eq!(feed(&mut d, &bytes[..12]), want[..1]);
        assert_eq!(d.stats().discarded, 3);
    }

    #[test]
    fn words_by_hand() {
        // +18 in of 36: 16384 = 0x4000; 14 bits 0x1000 -> LS 0x00, MS 0x20.
        assert_eq!(encode_word(0x4000), [0x00, 0x20]);
        assert_eq!(decode_word(0x00, 0x20), 0x4000);
        // -36 in: -32768 = 0x8000; 14 bits 0x2000 -> LS 0x00, MS 0x40.
        assert_eq!(encode_word(i16::MIN), [0x00, 0x40]);
        assert_eq!(decode_word(0x00, 0x40), i16::MIN);
        // 0.
        assert_eq!(encode_word(0), [0x00, 0x00]);
        // Largest word: 0x7ffc -> 14 bits 0x1fff -> LS 0x7f, MS 0x3f.
        assert_eq!(encode_word(0x7ffc), [0x7f, 0x3f]);
        assert_eq!(decode_word(0x7f, 0x3f), 0x7ffc);
        // -4 (one step below 0): 0xfffc -> 14 bits 0x3fff -> LS 0x7f, MS 0x7f.
        assert_eq!(encode_word(-4), [0x7f, 0x7f]);
        assert_eq!(decode_word(0x7f, 0x7f), -4);
        // The phasing bit and bit 7 of the MS byte do not reach the value.
        assert_eq!(decode_word(0x80, 0x20), 0x4000);
        assert_eq!(decode_word(0xff, 0xff), -4);
    }

    #[test]
    fn records_by_hand() {
        // X = +18 in, Y = -36 in, Z = 0; azimuth 90°, elevation -180° (= +180°), roll 0.
        let mut out = [0u8; 12];
        let r = rec([18.0, -36.0, 0.0], [90.0, -180.0, 0.0]);
        assert_eq!(encode(RecordFormat::PositionAngles, FS, &r, &mut out), 12);
        let expected = [
            0x80, 0x20, // X: 0x4000, phasing bit
            0x00, 0x40, // Y: 0x8000
            0x00, 0x00, // Z: 0
            0x00, 0x20, // azimuth 90°: 0x4000
            0x00, 0x40, // elevation -180°: 0x8000
            0x00, 0x00, // roll 0
        ];
        assert_eq!(out, expected);
        let mut d = Decoder::new(RecordFormat::PositionAngles, FS);
        assert_eq!(feed(&mut d, &expected), vec![r]);

        // 1 in at 36 in: 1/36*8192 = 227.56 -> 228 steps = 0xe4 -> LS 0x64, MS 0x01;
        // back: 228*4/32768*36 = 1.00195 in.
        let mut out = [0u8; 12];
        let r = Record {
            position_in: [1.0, 0.0, 0.0],
            angles_deg: None,
        };
        assert_eq!(encode(RecordFormat::Position, FS, &r, &mut out), 6);
        assert_eq!(out[..6], [0xe4, 0x01, 0, 0, 0, 0]);
        let got = decode_record(RecordFormat::Position, FS, &out[..6]).unwrap();
        assert!((got.position_in[0] - 228.0 * 4.0 / 32768.0 * 36.0).abs() < 1e-12);
        assert_eq!(got.angles_deg, None);

        // 72 in full scale: +36 in is half scale, the same bytes as +18 at 36.
        let r = Record {
            position_in: [36.0, 0.0, 0.0],
            angles_deg: None,
        };
        encode(RecordFormat::Position, 72.0, &r, &mut out);
        assert_eq!(out[..2], [0x80, 0x20]);
    }

    #[test]
    fn encode_saturates_positions_and_wraps_angles() {
        let mut out = [0u8; 12];
        let r = rec([36.0, 1e9, -1e9], [180.0, 190.0, -540.0]);
        encode(RecordFormat::PositionAngles, FS, &r, &mut out);
        let got = decode_record(RecordFormat::PositionAngles, FS, &out).unwrap();
        let top = 0x7ffc as f64 / 32768.0 * FS;
        assert_eq!(got.position_in, [top, top, -FS]);
        let a = got.angles_deg.unwrap();
        assert_eq!(a[0], -180.0);
        assert!((a[1] - -170.0).abs() <= ANG_LSB, "{a:?}");
        assert_eq!(a[2], -180.0);

        let r = rec([f64::NAN, f64::INFINITY, f64::NEG_INFINITY], [f64::NAN; 3]);
        encode(RecordFormat::PositionAngles, FS, &r, &mut out);
        let got = decode_record(RecordFormat::PositionAngles, FS, &out).unwrap();
        assert_eq!(got.position_in, [0.0, top, -FS]);
        assert_eq!(got.angles_deg, Some([0.0; 3]));

        // No angles in a POSITION/ANGLES record: zeros go out.
        let r = Record {
            position_in: [1.0, 2.0, 3.0],
            angles_deg: None,
        };
        encode(RecordFormat::PositionAngles, FS, &r, &mut out);
        assert_eq!(out[6..], [0; 6]);
    }

    #[test]
    fn round_trip_within_one_lsb_over_the_full_range() {
        let mut out = [0u8; 12];
        let n = 4001;
        for k in 0..n {
            let t = k as f64 / (n - 1) as f64; // 0..=1
            let p = -FS + 2.0 * FS * t;
            let a = -180.0 + 360.0 * t;
            let r = rec([p, -p, 0.5 * p], [a, -a, 0.5 * a]);
            encode(RecordFormat::PositionAngles, FS, &r, &mut out);
            let got = decode_record(RecordFormat::PositionAngles, FS, &out).unwrap();
            for i in 0..3 {
                assert!(
                    (got.position_in[i] - r.position_in[i]).abs() <= POS_LSB,
                    "{p} -> {:?}",
                    got.position_in
                );
                let want = r.angles_deg.unwrap()[i];
                let have = got.angles_deg.unwrap()[i];
                assert!(angle_diff(have, want) <= ANG_LSB, "{want} -> {have}");
                assert!((-180.0..180.0).contains(&have));
            }
        }
        // Other full scale.
        let r = Record {
            position_in: [71.99, -72.0, 12.345],
            angles_deg: None,
        };
        encode(RecordFormat::Position, 72.0, &r, &mut out);
        let got = decode_record(RecordFormat::Position, 72.0, &out[..6]).unwrap();
        for i in 0..3 {
            assert!((got.position_in[i] - r.position_in[i]).abs() <= 72.0 / 8192.0);
        }
    }

    #[test]
    fn decode_record_checks_length_and_phasing() {
        let mut out = [0u8; 12];
        encode(
            RecordFormat::Position,
            FS,
            &rec([1.0; 3], [0.0; 3]),
            &mut out,
        );
        assert!(decode_record(RecordFormat::Position, FS, &out[..6]).is_some());
        assert!(decode_record(RecordFormat::Position, FS, &out[..5]).is_none());
        assert!(decode_record(RecordFormat::PositionAngles, FS, &out[..6]).is_none());
        let mut bad = out;
        bad[0] &= 0x7f;
        assert!(decode_record(RecordFormat::Position, FS, &bad[..6]).is_none());
        let mut bad = out;
        bad[3] |= 0x80;
        assert!(decode_record(RecordFormat::Position, FS, &bad[..6]).is_none());
    }

    /// Three different records back to back, and what they decode to.
    fn three_records() -> (Vec<u8>, Vec<Record>) {
        let mut bytes = Vec::new();
        let mut want = Vec::new();
        for k in 0..3 {
            let x = k as f64;
            let r = rec([x + 1.5, -2.0 * x, 10.0], [10.0 * x, -5.0, 45.0 + x]);
            let mut out = [0u8; 12];
            encode(RecordFormat::PositionAngles, FS, &r, &mut out);
            bytes.extend_from_slice(&out);
            want.push(decode_record(RecordFormat::PositionAngles, FS, &out).unwrap());
        }
        (bytes, want)
    }

    #[test]
    fn stream_starting_mid_record_resyncs() {
        let (bytes, want) = three_records();
        let mut d = Decoder::new(RecordFormat::PositionAngles, FS);
        assert_eq!(feed(&mut d, &bytes[5..]), want[1..]);
        assert_eq!(
            d.stats(),
            DecoderStats {
                records: 2,
                malformed: 0,
                dropped_bytes: 7,
                discarded: 0
            }
        );
    }

    #[test]
    fn lost_byte_costs_one_record() {
        let (mut bytes, want) = three_records();
        bytes.remove(4); // a byte in the middle of the first record
        let mut d = Decoder::new(RecordFormat::PositionAngles, FS);
        assert_eq!(feed(&mut d, &bytes), want[1..]);
        assert_eq!(
            d.stats(),
            DecoderStats {
                records: 2,
                malformed: 1,
                dropped_bytes: 0,
                discarded: 0
            }
        );

        // Losing the first byte of a record drops the rest of it instead.
        let (mut bytes, want) = three_records();
        bytes.remove(12);
        let mut d = Decoder::new(RecordFormat::PositionAngles, FS);
        assert_eq!(feed(&mut d, &bytes), vec![want[0], want[2]]);
        assert_eq!(
            d.stats(),
            DecoderStats {
                records: 2,
                malformed: 0,
                dropped_bytes: 11,
                discarded: 0
            }
        );
    }

    #[test]
    fn garbage_between_records_is_skipped() {
        let (bytes, want) = three_records();
        let mut stream = vec![0x00, 0x13, 0x7f];
        stream.extend_from_slice(&bytes[..12]);
        stream.extend_from_slice(&[0x01, 0x02, 0x03]); // no phasing bit: dropped
        stream.extend_from_slice(&bytes[12..24]);
        stream.extend_from_slice(&[0xff, 0x05]); // phasing bit: a short bogus record
        stream.extend_from_slice(&bytes[24..]);
        let mut d = Decoder::new(RecordFormat::PositionAngles, FS);
        assert_eq!(feed(&mut d, &stream), want);
        assert_eq!(
            d.stats(),
            DecoderStats {
                records: 3,
                malformed: 1,
                dropped_bytes: 6,
                discarded: 0
            }
        );
    }

    #[test]
    fn reset_forgets_a_partial_record_without_counting_it() {
        let (bytes, want) = three_records();
        let mut d = Decoder::new(RecordFormat::PositionAngles, FS);
        assert!(feed(&mut d, &bytes[..7]).is_empty());
        assert_eq!(d.pending(), 7);
        d.reset();
        assert_eq!(d.pending(), 0);
        assert_eq!(feed(&mut d, &bytes[12..]), want[1..]);
        assert_eq!(d.stats().malformed, 0);
        assert_eq!(d.stats().dropped_bytes, 0);
    }

    #[test]
    fn position_records_decode_too() {
        let mut bytes = Vec::new();
        let mut out = [0u8; 12];
        for k in 0..4 {
            let r = Record {
                position_in: [k as f64, -(k as f64), 3.25],
                angles_deg: None,
            };
            let n = encode(RecordFormat::Position, FS, &r, &mut out);
            bytes.extend_from_slice(&out[..n]);
        }
        let mut d = Decoder::new(RecordFormat::Position, FS);
        let got = feed(&mut d, &bytes);
        assert_eq!(got.len(), 4);
        for (k, r) in got.iter().enumerate() {
            assert!((r.position_in[0] - k as f64).abs() <= POS_LSB);
            assert!((r.position_in[2] - 3.25).abs() <= POS_LSB);
            assert_eq!(r.angles_deg, None);
        }
    }

    #[test]
    fn random_bytes_never_panic_and_stats_add_up() {
        struct XorShift(u64);
        impl XorShift {
            fn next(&mut self) -> u64 {
                self.0 ^= self.0 << 13;
                self.0 ^= self.0 >> 7;
                self.0 ^= self.0 << 17;
                self.0
            }
        }
        for format in [RecordFormat::Position, RecordFormat::PositionAngles] {
            let mut rng = XorShift(0x2545_f491_4f6c_dd1d);
            let mut d = Decoder::new(format, FS);
            let total = 100_000u64;
            let (mut phased, mut emitted) = (0u64, 0u64);
            for _ in 0..total {
                let b = rng.next() as u8;
                phased += u64::from(b & 0x80 != 0);
                if let Some(r) = d.push(b) {
                    emitted += 1;
                    assert!(r.position_in.iter().all(|p| p.abs() <= FS));
                    if let Some(a) = r.angles_deg {
                        assert!(a.iter().all(|x| (-180.0..180.0).contains(x)));
                    }
                }
                assert!(d.pending() < format.bytes());
            }
            let s = d.stats();
            assert_eq!(s.records, emitted);
            // Every record and every malformed partial began with a byte with the phasing bit;
            // the one in progress may too.
            let in_progress = u64::from(d.pending() > 0);
            assert_eq!(s.records + s.malformed + in_progress, phased);
            // Every byte is in exactly one place.
            assert!(s.dropped_bytes + s.records * format.bytes() as u64 <= total);
            // Random bytes have the phasing bit half the time, so a 6- or 12-byte run without
            // it is rare: few records, many malformed.
            assert!(s.malformed > s.records);
            assert!(s.dropped_bytes > 0);
        }
    }
}
