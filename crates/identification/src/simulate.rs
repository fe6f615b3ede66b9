//! A record from the simulated rig under an excitation plan: what `oilfilm simulate` writes
//! and what the identification tests identify. The exciter forces follow the plan (clamped by
//! its limits, as the exciter node will enforce them); the DAQ chain quantises and adds noise;
//! the truth (the film's operating point and linear coefficients) comes along for judging.

use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::DaqScan;
use oilfilm_physics::operating_point::OperatingPoint;
use oilfilm_physics::rig::{RigInput, RigSample};
use oilfilm_physics::simulation::SimulatedRig;

use crate::ascii::{self, Header, Record, Units};
use crate::error::IdentificationError;
use crate::excitation::{ExcitationPlan, Limits};
use crate::record::{RawRecord, RawUnits};

/// A simulated acquisition.
#[derive(Debug, Clone)]
pub struct SimulatedRecord {
    /// The DAQ's scans (volts), in order.
    pub scans: Vec<DaqScan>,
    /// The film's operating point at the start: equilibrium and the linear coefficients of
    /// the very film the rig integrates (the identification's reference).
    pub truth: OperatingPoint,
    /// The rig's true state at the end of each scan period, when asked for.
    pub states: Option<Vec<RigSample>>,
    pub sample_rate_hz: f64,
    pub speed_rpm: f64,
    pub rig_name: String,
}

/// What to keep besides the scans.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SimulateOptions {
    /// Keep the rig's true state per scan (memory: ~200 bytes a scan).
    pub keep_states: bool,
}

/// The exciter limits of a rig file.
pub fn limits_of(rig: &RigConfig) -> Limits {
    Limits { max_force_n: rig.housing.exciter_max_force_n, band_hz: rig.housing.exciter_band_hz }
}

/// Simulates `seconds` of the rig under `plan`. The plan is validated against the rig's
/// exciter limits first: a plan the exciters would refuse is refused here too.
/// `progress` is called with the fraction done, every 1 % or so.
pub fn simulate(
    rig: &RigConfig,
    plan: &ExcitationPlan,
    seconds: f64,
    options: SimulateOptions,
    progress: &mut dyn FnMut(f64),
) -> Result<SimulatedRecord, IdentificationError> {
    if !(seconds.is_finite() && seconds > 0.0) {
        return Err(IdentificationError::invalid("seconds", format!("must be finite and > 0, got {seconds}")));
    }
    let limits = limits_of(rig);
    plan.validate(&limits)?;
    let mut sim = SimulatedRig::new(rig, 0.0)?;
    let period = sim.period_s();
    let n = (seconds / period).round() as usize;
    if n == 0 {
        return Err(IdentificationError::invalid("seconds", format!("{seconds} s is shorter than one scan period")));
    }
    let mut scans = Vec::with_capacity(n);
    let mut states = options.keep_states.then(|| Vec::with_capacity(n));
    let step = (n / 100).max(1);
    for i in 1..=n {
        let t = i as f64 * period;
        let input = RigInput { exciter_n: plan.force_at(t, &limits) };
        let s = sim.step(&input, t)?;
        scans.push(s.scan);
        if let Some(v) = states.as_mut() {
            v.push(s.truth);
        }
        if i % step == 0 {
            progress(i as f64 / n as f64);
        }
    }
    Ok(SimulatedRecord {
        scans,
        truth: *sim.operating_point(),
        states,
        sample_rate_hz: rig.daq.sample_rate_hz,
        speed_rpm: rig.operating.speed_rpm,
        rig_name: rig.name.clone(),
    })
}

impl SimulatedRecord {
    /// The scans as a raw record (volts, scan order).
    pub fn raw(&self) -> Result<RawRecord, IdentificationError> {
        RawRecord::from_scans(&self.scans, self.sample_rate_hz)
    }

    /// The record in the ASCII format, in volts as the card read them or in SI through the
    /// rig's calibration.
    pub fn to_ascii(&self, rig: &RigConfig, units: Units) -> Result<Record, IdentificationError> {
        let raw = self.raw()?;
        let calibration = rig.daq.calibration();
        let mut header = Header::new_si(&self.rig_name, self.sample_rate_hz, rig.daq.channel_interval_s);
        header.units = units;
        header.speed_rpm = Some(self.speed_rpm);
        header.start_time_s = self.scans.first().map_or(0.0, |s| s.scan_start_s);
        header.channels = raw.channels.iter().map(|c| c.name().to_string()).collect();
        let columns = match units {
            Units::Volts => raw.columns,
            Units::Si => raw
                .channels
                .iter()
                .zip(&raw.columns)
                .map(|(&ch, col)| col.iter().map(|&v| calibration.to_si(ch, v)).collect::<Result<Vec<_>, _>>())
                .collect::<Result<Vec<_>, _>>()?,
        };
        let first = self.scans.first().map_or(0, |s| s.scan_index);
        let record = Record { header, scan_index: (first..first + self.scans.len() as u64).collect(), columns };
        // Round-trip guard: what we write must be what the reader accepts.
        record.header.validate()?;
        Ok(record)
    }
}

/// Converts an ASCII record to a raw record (channel names to ids, units kept).
pub fn raw_from_ascii(record: &Record) -> Result<RawRecord, IdentificationError> {
    let channels = record
        .header
        .channels
        .iter()
        .map(|name| oilfilm_physics::daq::ChannelId::parse(name).map_err(IdentificationError::from))
        .collect::<Result<Vec<_>, _>>()?;
    let first = record.scan_index.first().copied().unwrap_or(0);
    Ok(RawRecord {
        sample_rate_hz: record.header.sample_rate_hz,
        start_time_s: record.header.start_time_s + first as f64 / record.header.sample_rate_hz,
        channels,
        units: match record.header.units {
            Units::Volts => RawUnits::Volts,
            Units::Si => RawUnits::Si,
        },
        columns: record.columns.clone(),
    })
}

/// The text of a record (convenience over [`ascii::write`]).
pub fn ascii_text(record: &Record) -> Result<String, IdentificationError> {
    ascii::write(record)
}
