//! Packet framing of Protocol 2.0 (e-Manual "Protocol 2.0"): header, byte stuffing, CRC-16, and
//! the encoding of instruction and status packets. The bus parses the packets it receives in
//! [`Bus::receive`](super::Bus::receive).

use dynamixel2::checksum::calculate_checksum;

use super::table::instruction;

/// Packet ID that addresses every device.
pub const BROADCAST_ID: u8 = 0xFE;
/// Largest length field an instruction packet may have here (DynamixelSDK's packet buffer is 1 KiB);
/// a header announcing more is taken for garbage.
pub const MAX_PACKET_LENGTH: usize = 1024;

/// The header of every packet: 0xFF 0xFF 0xFD and a reserved 0x00 (which tells it from
/// stuffing).
pub(super) const HEADER: [u8; 4] = [0xFF, 0xFF, 0xFD, 0x00];

// ---------------------------------------------------------------------------------------------
// Byte stuffing (e-Manual "Protocol 2.0", Packet Process).

/// Byte stuffing: after every `FF FF FD` of `body` (instruction to last parameter) a `FD` is
/// inserted, so that the body never contains a header.
pub fn stuff(body: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(body.len() + body.len() / 3);
    for (i, &b) in body.iter().enumerate() {
        out.push(b);
        if i >= 2 && body[i - 2..=i] == [0xFF, 0xFF, 0xFD] {
            out.push(0xFD);
        }
    }
    out
}

/// Undoes [`stuff`]: every `FF FF FD FD` becomes `FF FF FD`.
pub fn unstuff(stuffed: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(stuffed.len());
    let mut i = 0;
    while i < stuffed.len() {
        if stuffed[i..].starts_with(&[0xFF, 0xFF, 0xFD, 0xFD]) {
            out.extend_from_slice(&[0xFF, 0xFF, 0xFD]);
            i += 4;
        } else {
            out.push(stuffed[i]);
            i += 1;
        }
    }
    out
}

/// A whole packet: header, `id`, length, the stuffed `body` (instruction onwards), CRC-16.
fn packet(id: u8, body: &[u8]) -> Vec<u8> {
    let stuffed = stuff(body);
    let length = u16::try_from(stuffed.len() + 2).unwrap_or(u16::MAX);
    let mut p = Vec::with_capacity(stuffed.len() + 9);
    p.extend_from_slice(&HEADER);
    p.push(id);
    p.extend_from_slice(&length.to_le_bytes());
    p.extend_from_slice(&stuffed);
    let crc = calculate_checksum(0, &p);
    p.extend_from_slice(&crc.to_le_bytes());
    p
}

/// Encodes an instruction packet as a master sends it (byte stuffing and CRC included).
pub fn instruction_packet(id: u8, instruction: u8, params: &[u8]) -> Vec<u8> {
    let mut body = Vec::with_capacity(params.len() + 1);
    body.push(instruction);
    body.extend_from_slice(params);
    packet(id, &body)
}

/// Encodes a status packet as a device sends it: instruction 0x55, `error`, `params`.
pub fn status_packet(id: u8, error: u8, params: &[u8]) -> Vec<u8> {
    let mut body = Vec::with_capacity(params.len() + 2);
    body.push(instruction::STATUS);
    body.push(error);
    body.extend_from_slice(params);
    packet(id, &body)
}

/// A status packet whose length field is below 4 (no room for instruction and error) but
/// whose CRC, at the place that length gives, is right: bytes dynamixel2 0.9.1 panics on
/// (see the tests of the bus). For [`Bus::inject_raw`](super::Bus::inject_raw), to prove a
/// driver survives them.
pub fn short_status_packet(id: u8, length: u16) -> Vec<u8> {
    let mut p = HEADER.to_vec();
    p.push(id);
    p.extend(length.to_le_bytes());
    // Length counts the bytes after itself including the CRC: fill the rest but the CRC.
    p.extend(std::iter::repeat_n(
        0x55,
        usize::from(length.saturating_sub(2)),
    ));
    let crc = calculate_checksum(0, &p);
    p.extend(crc.to_le_bytes());
    p
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamixel::testing::bytes;

    #[test]
    fn our_encoder_reproduces_the_manual_packets() {
        assert_eq!(
            instruction_packet(1, instruction::PING, &[]),
            bytes("FF FF FD 00 01 03 00 01 19 4E")
        );
        assert_eq!(
            instruction_packet(0xFE, instruction::SYNC_READ, &bytes("84 00 04 00 01 02")),
            bytes("FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA")
        );
        assert_eq!(
            status_packet(2, 0, &bytes("1F 08 00 00")),
            bytes("FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE")
        );
    }

    #[test]
    fn stuffing_round_trip() {
        let cases: &[&[u8]] = &[
            &[],
            &[0xFF, 0xFF, 0xFD],
            &[0xFF, 0xFF, 0xFD, 0xFD],
            &[0xFF, 0xFF, 0xFF, 0xFD],
            &[0xFF, 0xFF, 0xFF, 0xFF, 0xFD, 0xFD, 0xFF, 0xFF],
            &[0xFF, 0xFF, 0xFD, 0xFF, 0xFF, 0xFD, 0x00],
            &[0x00, 0xFF, 0xFF, 0xFD, 0x00],
        ];
        for &c in cases {
            assert_eq!(unstuff(&stuff(c)), c, "{c:02X?}");
        }
        assert_eq!(stuff(&[0xFF, 0xFF, 0xFD]), [0xFF, 0xFF, 0xFD, 0xFD]);
        assert_eq!(
            stuff(&[0xFF, 0xFF, 0xFF, 0xFD]),
            [0xFF, 0xFF, 0xFF, 0xFD, 0xFD]
        );
        // Exhaustively over short words of the bytes that matter.
        let alphabet = [0x00, 0xFD, 0xFF];
        for len in 0..=7u32 {
            for n in 0..3usize.pow(len) {
                let word: Vec<u8> = (0..len).map(|k| alphabet[n / 3usize.pow(k) % 3]).collect();
                let stuffed = stuff(&word);
                assert_eq!(unstuff(&stuffed), word);
                assert!(!stuffed.windows(4).any(|w| w == HEADER), "{word:02X?}");
            }
        }
    }
}
