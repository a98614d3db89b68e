//! The CRC-16 every message carries in its header.

/// CRC-16/CCITT-FALSE (polynomial 0x1021, initial value 0xFFFF): it detects
/// every error of one, two or an odd number of bits, and every burst of up
/// to 16, in messages as short as ours.
const CRC_TABLES: [[u16; 256]; 8] = {
    let mut tables = [[0u16; 256]; 8];
    let mut i = 0;
    while i < 256 {
        let mut crc = (i as u16) << 8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
            bit += 1;
        }
        tables[0][i] = crc;
        i += 1;
    }
    // tables[k][i]: byte i followed by k zero bytes.
    let mut k = 1;
    while k < 8 {
        let mut i = 0;
        while i < 256 {
            let prev = tables[k - 1][i];
            tables[k][i] = (prev << 8) ^ tables[0][(prev >> 8) as usize];
            i += 1;
        }
        k += 1;
    }
    tables
};

/// Eight bytes a step ("slicing by eight"): the register meets the first
/// two, and each byte's share of the remainder is one lookup, so the eight
/// lookups do not wait on each other as the byte-wise loop's do. Every
/// message is checksummed when sent and when received, and byte by byte
/// that was 2 % of a node process's CPU in `cqnet run`.
pub(super) fn crc16(mut crc: u16, bytes: &[u8]) -> u16 {
    let t = &CRC_TABLES;
    let mut chunks = bytes.chunks_exact(8);
    for c in &mut chunks {
        crc = t[7][((crc >> 8) as u8 ^ c[0]) as usize]
            ^ t[6][(crc as u8 ^ c[1]) as usize]
            ^ t[5][c[2] as usize]
            ^ t[4][c[3] as usize]
            ^ t[3][c[4] as usize]
            ^ t[2][c[5] as usize]
            ^ t[1][c[6] as usize]
            ^ t[0][c[7] as usize];
    }
    crc16_bytewise(crc, chunks.remainder())
}

fn crc16_bytewise(mut crc: u16, bytes: &[u8]) -> u16 {
    for b in bytes {
        crc = (crc << 8) ^ CRC_TABLES[0][((crc >> 8) as u8 ^ b) as usize];
    }
    crc
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_checksum_is_crc16_ccitt_false() {
        // The catalogue's check value for this CRC, byte by byte and eight
        // at a time (with one byte left over).
        assert_eq!(crc16_bytewise(0xFFFF, b"123456789"), 0x29B1);
        assert_eq!(crc16(0xFFFF, b"123456789"), 0x29B1);
    }

    /// Slicing by eight is the byte-wise CRC, from any register, at every
    /// length around the eight-byte chunks.
    #[test]
    fn eight_bytes_a_step_is_the_bytewise_crc() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for len in 0..=80 {
            for _ in 0..20 {
                let bytes: Vec<u8> = (0..len).map(|_| rng.random()).collect();
                let start: u16 = rng.random();
                assert_eq!(
                    crc16(start, &bytes),
                    crc16_bytewise(start, &bytes),
                    "{len} bytes from {start:#06x}"
                );
            }
        }
    }
}
