//! A raw record: the DAQ's readings of one run, one column per channel in scan order, in
//! volts or already in SI. The ASCII and foreign-record readers, the simulator and a bag's
//! DAQ frames all produce one; the conditioning turns it into what the estimator reads.

use oilfilm_physics::daq::{ChannelId, DaqScan, CHANNEL_COUNT};
use serde::{Deserialize, Serialize};

use crate::IdentificationError;

/// The unit of a raw record's columns.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RawUnits {
    /// Amplifier volts as read by the ADC; calibrated here.
    Volts,
    /// Already in the channel's SI unit (m, N, degC).
    Si,
}

impl RawUnits {
    /// `"volts"` or `"si"`.
    pub fn name(self) -> &'static str {
        match self {
            RawUnits::Volts => "volts",
            RawUnits::Si => "si",
        }
    }
}

/// A raw record: one column per channel in scan order, sample `i` of every column belonging
/// to the scan that started at `start_time_s + i / sample_rate_hz`.
#[derive(Clone, Debug, PartialEq)]
pub struct RawRecord {
    /// Scans per second.
    pub sample_rate_hz: f64,
    /// Start time of the first scan (s).
    pub start_time_s: f64,
    /// Channel of each column, in scan order.
    pub channels: Vec<ChannelId>,
    pub units: RawUnits,
    pub columns: Vec<Vec<f64>>,
}

impl RawRecord {
    /// Transposes a sequence of consecutive scans (volts) into columns. The scans must share
    /// one channel order and be spaced `1 / sample_rate_hz` apart (within 0.1 % of a period):
    /// a gap, a repeated or out-of-order scan is a `BadInput` naming the scan.
    pub fn from_scans(scans: &[DaqScan], sample_rate_hz: f64) -> Result<Self, IdentificationError> {
        if !(sample_rate_hz.is_finite() && sample_rate_hz > 0.0) {
            return Err(IdentificationError::invalid("sample_rate_hz", format!("must be finite and > 0, got {sample_rate_hz}")));
        }
        let Some(first) = scans.first() else {
            return Err(IdentificationError::BadInput { what: "scans".into(), reason: "no scans".into() });
        };
        let channels = first.channels.clone();
        let start = first.scan_start_s;
        if !start.is_finite() {
            return Err(IdentificationError::BadInput { what: "scans[0].scan_start_s".into(), reason: format!("not finite ({start})") });
        }
        let period = 1.0 / sample_rate_hz;
        let mut columns: Vec<Vec<f64>> = (0..channels.len()).map(|_| Vec::with_capacity(scans.len())).collect();
        for (i, s) in scans.iter().enumerate() {
            if s.channels != channels || s.volts.len() != channels.len() {
                return Err(IdentificationError::BadInput {
                    what: format!("scans[{i}] (scan_index {})", s.scan_index),
                    reason: format!(
                        "channels {:?} with {} readings; scans[0] has {:?}",
                        s.channels.iter().map(|c| c.name()).collect::<Vec<_>>(),
                        s.volts.len(),
                        channels.iter().map(|c| c.name()).collect::<Vec<_>>()
                    ),
                });
            }
            let expected = start + i as f64 * period;
            let deviation = (s.scan_start_s - expected).abs();
            if deviation.is_nan() || deviation > 1.0e-3 * period {
                return Err(IdentificationError::BadInput {
                    what: format!("scans[{i}].scan_start_s (scan_index {})", s.scan_index),
                    reason: format!("{} s, expected {expected} s at {sample_rate_hz} scans/s: missing, repeated or out-of-order scan", s.scan_start_s),
                });
            }
            for (col, &v) in columns.iter_mut().zip(&s.volts) {
                col.push(v);
            }
        }
        Ok(Self { sample_rate_hz, start_time_s: start, channels, units: RawUnits::Volts, columns })
    }

    /// Samples per column (of the first column; [`RawRecord::validate_shape`] checks the rest).
    pub fn len(&self) -> usize {
        self.columns.first().map_or(0, Vec::len)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The column of `channel`, if present.
    pub fn column(&self, channel: ChannelId) -> Option<&[f64]> {
        self.channels.iter().position(|&c| c == channel).and_then(|k| self.columns.get(k)).map(Vec::as_slice)
    }

    /// Checks the shape: finite positive sample rate, finite start time, one column per
    /// channel, no channel twice, all columns the same non-zero length.
    pub fn validate_shape(&self) -> Result<(), IdentificationError> {
        if !(self.sample_rate_hz.is_finite() && self.sample_rate_hz > 0.0) {
            return Err(IdentificationError::invalid("sample_rate_hz", format!("must be finite and > 0, got {}", self.sample_rate_hz)));
        }
        if !self.start_time_s.is_finite() {
            return Err(IdentificationError::BadInput { what: "start_time_s".into(), reason: format!("not finite ({})", self.start_time_s) });
        }
        if self.channels.len() != self.columns.len() {
            return Err(IdentificationError::BadInput {
                what: "columns".into(),
                reason: format!("{} columns for {} channels", self.columns.len(), self.channels.len()),
            });
        }
        let mut seen = [false; CHANNEL_COUNT];
        for &c in &self.channels {
            if std::mem::replace(&mut seen[c.index()], true) {
                return Err(IdentificationError::BadInput { what: format!("channel `{c}`"), reason: "appears twice in the record".into() });
            }
        }
        let n = self.len();
        if n == 0 {
            return Err(IdentificationError::BadInput { what: "columns".into(), reason: "the record has no samples".into() });
        }
        for (c, col) in self.channels.iter().zip(&self.columns) {
            if col.len() != n {
                return Err(IdentificationError::BadInput {
                    what: format!("column `{c}`"),
                    reason: format!("{} samples, but `{}` has {n}: ragged columns", col.len(), self.channels[0]),
                });
            }
        }
        Ok(())
    }
}
