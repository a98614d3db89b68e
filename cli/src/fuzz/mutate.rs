//! The mutators: bytes edited at random for the wire and the actors, and
//! line- and value-level edits that keep a scenario mostly TOML.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Values that have broken parsers and validators before.
pub(super) const INTERESTING: &[&str] = &[
    "0",
    "-1",
    "-5",
    "1",
    "2",
    "255",
    "256",
    "65535",
    "65536",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "99999999999999999999",
    "1e308",
    "-1e308",
    "1e-320",
    "0.0",
    "-0.0",
    "nan",
    "inf",
    "-inf",
    "0.5",
    "\"\"",
    "\"sonar\"",
    "\"bearing\"",
    "\"exact\"",
    "true",
    "[]",
    "[0,0]",
    "[1,0]",
    "[1000,1000]",
    "[-1,3]",
    "[1e9,1e9]",
    "[[]]",
    "{}",
    "{a=1}",
    "\"node-42\"",
    "\"node-0\"",
    "\"sensor-99999\"",
    "\"launcher\"",
    "[\"node-0\"]",
    "'",
    "\"",
    "[",
    "=",
    "#",
];

pub(super) fn mutate_bytes(input: &mut Vec<u8>, rng: &mut ChaCha8Rng) {
    let len = input.len();
    let at = |rng: &mut ChaCha8Rng| rng.random_range(0..=len);
    match rng.random_range(0..9) {
        0 if len > 0 => {
            let i = rng.random_range(0..len);
            input[i] ^= 1 << rng.random_range(0..8);
        }
        1 if len > 0 => {
            let i = rng.random_range(0..len);
            input[i] = [0, 1, 0x7f, 0x80, 0xfe, 0xff][rng.random_range(0..6)];
        }
        2 => {
            let i = at(rng);
            let n = rng.random_range(1..16);
            let bytes: Vec<u8> = (0..n).map(|_| rng.random()).collect();
            input.splice(i..i, bytes);
        }
        3 if len > 0 => {
            let i = rng.random_range(0..len);
            let n = rng.random_range(1..=(len - i).min(16));
            input.drain(i..i + n);
        }
        4 => {
            let n = at(rng);
            input.truncate(n);
        }
        5 if len >= 8 => {
            // A float field made special.
            let i = rng.random_range(0..=len - 8);
            let v = [
                f64::NAN,
                f64::INFINITY,
                f64::NEG_INFINITY,
                0.0,
                -0.0,
                f64::MAX,
                1e-310,
            ][rng.random_range(0..7)];
            input[i..i + 8].copy_from_slice(&v.to_le_bytes());
        }
        6 if len >= 2 => {
            let i = rng.random_range(0..=len - 2);
            let v = [0u16, 1, 0x7fff, 0x8000, 0xffff, 255, 256][rng.random_range(0..7)];
            input[i..i + 2].copy_from_slice(&v.to_le_bytes());
        }
        7 if len > 0 => {
            let i = rng.random_range(0..len);
            let n = rng.random_range(1..=(len - i).min(32));
            let copy = input[i..i + n].to_vec();
            let j = at(rng);
            input.splice(j..j, copy);
        }
        _ => input.push(rng.random()),
    }
}

/// Line- and value-level edits that keep a TOML file mostly TOML, so that
/// inputs get past the parser to the validation behind it.
pub(super) fn mutate_text(input: &mut Vec<u8>, rng: &mut ChaCha8Rng) {
    let text = String::from_utf8_lossy(input).into_owned();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    if lines.is_empty() {
        lines.push(String::new());
    }
    let i = rng.random_range(0..lines.len());
    match rng.random_range(0..6) {
        0 | 1 => {
            if let Some(eq) = lines[i].find('=') {
                let value = INTERESTING[rng.random_range(0..INTERESTING.len())];
                lines[i] = format!("{}= {value}", &lines[i][..eq]);
            }
        }
        2 => {
            lines.remove(i);
        }
        3 => {
            let copy = lines[rng.random_range(0..lines.len())].clone();
            lines.insert(i, copy);
        }
        4 => {
            let j = rng.random_range(0..lines.len());
            lines.swap(i, j);
        }
        _ => {
            // A number in the line scaled, negated or zeroed.
            let line = &lines[i];
            if let Some(start) = line.find(|c: char| c.is_ascii_digit()) {
                let end = line[start..]
                    .find(|c: char| !(c.is_ascii_digit() || c == '.'))
                    .map_or(line.len(), |e| start + e);
                let n = ["0", "-1", "100000", "1e20", "0.000001", "7"][rng.random_range(0..6)];
                lines[i] = format!("{}{n}{}", &line[..start], &line[end..]);
            }
        }
    }
    *input = lines.join("\n").into_bytes();
}

/// Every dotted key of a TOML document (`filter.particles`, …).
pub(super) fn scenario_keys(text: &str) -> Vec<String> {
    fn walk(prefix: &str, v: &toml::Value, out: &mut Vec<String>) {
        if let toml::Value::Table(t) = v {
            for (k, v) in t {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                walk(&key, v, out);
                out.push(key);
            }
        }
    }
    let mut keys = Vec::new();
    if let Ok(t) = text.parse::<toml::Table>() {
        walk("", &toml::Value::Table(t), &mut keys);
    }
    keys
}
