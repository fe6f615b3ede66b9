//! A simulated record: the rig and its DAQ chain stepped together, scan by scan.
//!
//! Each call to [`SimulatedRig::step`] advances the rig by one DAQ period with the exciter
//! forces given for the end of the period, then samples one multiplexed scan that starts at
//! the beginning of the period: channel k is read k channel-intervals after the scan start,
//! from the rig's interpolated trajectory. Everything is seeded by the configuration, so a
//! record is reproducible bit for bit.

use crate::config::RigConfig;
use crate::daq::{Daq, DaqScan};
use crate::error::PhysicsError;
use crate::operating_point::OperatingPoint;
use crate::rig::{Rig, RigInput, RigSample};

/// The rig and its DAQ.
#[derive(Debug)]
pub struct SimulatedRig {
    rig: Rig,
    daq: Daq,
    period_s: f64,
    scan_index: u64,
}

/// One scan of a simulated record and the truth behind it.
#[derive(Debug, Clone, PartialEq)]
pub struct SimulatedScan {
    pub scan: DaqScan,
    /// The rig's true state at the end of the period (the next scan's start).
    pub truth: RigSample,
}

impl SimulatedRig {
    /// A rig at static equilibrium at `start_s`, with the configuration's seed.
    pub fn new(config: &RigConfig, start_s: f64) -> Result<Self, PhysicsError> {
        let daq = Daq::new(&config.daq, &config.effects, config.simulation.seed)?;
        let rig = Rig::new(config, start_s, daq.max_lookback_s())?;
        Ok(Self { rig, daq, period_s: 1.0 / config.daq.sample_rate_hz, scan_index: 0 })
    }

    /// The DAQ period, s.
    pub fn period_s(&self) -> f64 {
        self.period_s
    }

    /// The film's operating point at the start.
    pub fn operating_point(&self) -> &OperatingPoint {
        self.rig.operating_point()
    }

    /// The rig, for its truth.
    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// The time the next scan starts.
    pub fn time_s(&self) -> f64 {
        self.rig.time_s()
    }

    /// Advances one DAQ period to `stamp_s` (normally `time_s() + period_s()`) with the
    /// exciter forces acting at `stamp_s`, and samples the scan that started at `time_s()`.
    pub fn step(&mut self, input: &RigInput, stamp_s: f64) -> Result<SimulatedScan, PhysicsError> {
        let scan_start = self.rig.time_s();
        let truth = self.rig.step(input, stamp_s)?;
        let rig = &self.rig;
        let scan = self.daq.scan(self.scan_index, scan_start, &mut |t| rig.signals_at(t));
        self.scan_index += 1;
        Ok(SimulatedScan { scan, truth })
    }
}
