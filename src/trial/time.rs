//! UTC timestamps written as ISO-8601 (`2025-03-01T14:05:09.250Z`), millisecond precision
//! (formatted by [`crate::clock::format_utc`]).
//!
//! Callers pass timestamps in (the log never reads the clock itself), so tests can
//! use fixed times; [`UtcTimestamp::now`] is for the command line.

use super::TrialError;
use crate::clock::{days_from_civil, format_utc, unix_ms_now, UtcPrecision};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// A UTC instant, milliseconds since the Unix epoch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct UtcTimestamp {
    /// Milliseconds since 1970-01-01T00:00:00Z (negative before).
    pub unix_ms: i64,
}

impl UtcTimestamp {
    /// The current system time.
    pub fn now() -> Self {
        UtcTimestamp {
            unix_ms: unix_ms_now(),
        }
    }

    /// The instant `unix_ms` milliseconds after the epoch.
    pub fn from_unix_ms(unix_ms: i64) -> Self {
        UtcTimestamp { unix_ms }
    }
}

fn days_in_month(year: i64, month: u32) -> u32 {
    match month {
        2 if (year % 4 == 0 && year % 100 != 0) || year % 400 == 0 => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    }
}

impl fmt::Display for UtcTimestamp {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&format_utc(self.unix_ms, UtcPrecision::Millis))
    }
}

impl FromStr for UtcTimestamp {
    type Err = TrialError;

    /// Parses `YYYY-MM-DDTHH:MM:SS[.f{1,9}]Z` (a space may replace `T`; fractions
    /// beyond milliseconds are truncated).
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let bad = || TrialError::BadTimestamp {
            text: text.to_string(),
        };
        let b = text.as_bytes();
        if !text.is_ascii()
            || b.len() < 20
            || b[4] != b'-'
            || b[7] != b'-'
            || !(b[10] == b'T' || b[10] == b' ')
        {
            return Err(bad());
        }
        if b[13] != b':' || b[16] != b':' || *b.last().ok_or_else(bad)? != b'Z' {
            return Err(bad());
        }
        let num = |range: std::ops::Range<usize>| -> Result<i64, TrialError> {
            let s = &text[range];
            if s.bytes().all(|c| c.is_ascii_digit()) {
                s.parse::<i64>().map_err(|_| bad())
            } else {
                Err(bad())
            }
        };
        let year = num(0..4)?;
        let month = num(5..7)? as u32;
        let day = num(8..10)? as u32;
        let (hour, minute, second) = (num(11..13)?, num(14..16)?, num(17..19)?);
        if !(1..=12).contains(&month)
            || day == 0
            || day > days_in_month(year, month)
            || hour > 23
            || minute > 59
            || second > 59
        {
            return Err(bad());
        }
        let frac = &text[19..text.len() - 1];
        let millis = if frac.is_empty() {
            0
        } else {
            let digits = frac.strip_prefix('.').ok_or_else(bad)?;
            if digits.is_empty() || digits.len() > 9 || !digits.bytes().all(|c| c.is_ascii_digit())
            {
                return Err(bad());
            }
            let padded = format!("{digits:0<3}");
            padded[..3].parse::<i64>().map_err(|_| bad())?
        };
        let days = days_from_civil(year, month, day);
        Ok(UtcTimestamp {
            unix_ms: ((days * 24 + hour) * 60 + minute) * 60_000 + second * 1000 + millis,
        })
    }
}

impl Serialize for UtcTimestamp {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for UtcTimestamp {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let text = String::deserialize(d)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // Reference instants from `date -u -d ... +%s` (GNU coreutils).
    const KNOWN: &[(&str, i64)] = &[
        ("1970-01-01T00:00:00.000Z", 0),
        ("2000-03-01T00:00:00.000Z", 951_868_800),
        ("2024-02-29T12:00:00.000Z", 1_709_208_000),
        ("1969-12-31T23:59:59.000Z", -1),
        ("2100-03-01T00:00:00.000Z", 4_107_542_400),
    ];

    #[test]
    fn formats_and_parses_known_instants() {
        for &(text, secs) in KNOWN {
            let t = UtcTimestamp::from_unix_ms(secs * 1000);
            assert_eq!(t.to_string(), text);
            assert_eq!(text.parse::<UtcTimestamp>().unwrap(), t);
        }
        let t: UtcTimestamp = "2024-02-29T12:00:00.25Z".parse().unwrap();
        assert_eq!(t.unix_ms, 1_709_208_000_250);
        let t: UtcTimestamp = "2024-02-29 12:00:00Z".parse().unwrap();
        assert_eq!(t.unix_ms, 1_709_208_000_000);
    }

    #[test]
    fn round_trips_over_many_days() {
        // Every 7919th second over ~400 years, with milliseconds.
        let mut ms = -2_208_988_800_000_i64; // 1900-01-01
        while ms < 10_413_792_000_000 {
            let t = UtcTimestamp::from_unix_ms(ms);
            assert_eq!(t.to_string().parse::<UtcTimestamp>().unwrap(), t);
            ms += 7_919_123;
        }
    }

    #[test]
    fn rejects_malformed_timestamps() {
        for bad in [
            "",
            "2024-02-30T00:00:00Z",
            "2023-02-29T00:00:00Z",
            "2024-13-01T00:00:00Z",
            "2024-01-01T24:00:00Z",
            "2024-01-01T00:00:00",
            "2024-01-01T00:00:00.Z",
            "2024-01-01T00:00:00+01:00",
            "2024-1-01T00:00:00Z",
            "2024-01-01T00:00:0xZ",
        ] {
            assert!(
                matches!(
                    bad.parse::<UtcTimestamp>(),
                    Err(TrialError::BadTimestamp { .. })
                ),
                "{bad}"
            );
        }
    }
}
