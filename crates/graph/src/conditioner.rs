//! The conditioner node's core: DAQ frames in, conditioned frames out, through the very
//! conditioning chain offline identification uses (`oilfilm_identification::conditioning`,
//! Zhou et al. 2004 section 3.1 steps 1-7).
//!
//! Streaming zero-phase filtering: the chain is non-causal (forward-backward low-pass,
//! centred derivatives, de-skew interpolation), so an output block of `block_scans` samples
//! is out once `edge` raw samples past it are in, where `edge` is what the chain itself trims
//! from a record ([`conditioning::Chain::edge`]). The front end and the low-pass's forward
//! pass run once per scan, carried from frame to frame, and each block's backward pass starts
//! on the forward output past it ([`conditioning::stream`], ADR 0019); a block whose window
//! (`edge` scans on either side) holds a reading the front end cannot use is conditioned as
//! that window of raw scans instead, which names the reading. Blocks sit at fixed scan
//! indices of the stream, so the output depends only on the input scans, never on how they
//! were cut into frames or when they arrived: live and replayed graphs give the same bits.
//! Latency is one block plus `edge` scans.
//!
//! ## The causal chain (`chain: causal`, ADR 0014)
//! The same steps run forward only, scan by scan, with their state carried across frames
//! ([`conditioning::causal`]): de-skew at a fixed common delay, a Butterworth low-pass of
//! order `2 x lowpass_order` (its stop band falls as the zero-phase `|H|^2` does), the
//! Savitzky-Golay derivatives and eq. 2 at one common delay. A sample is out `L + 2M` scans
//! (11 on the Zhou card's schedule) after its scan came in, instead of after the zero-phase edge; the
//! frames still hold `block_scans` samples at fixed scan indices, so live and replayed
//! graphs give the same bits here too. Those indices are multiples of `block_scans` (the
//! samples before the first multiple are dropped when a stream starts), as the estimator's
//! windows are multiples of its hop: with a window and hop that are multiples of
//! `block_scans`, a window's last block is out `L + 2M` scans after its last sample. A sample's `first_sample` index (and the stamp) is
//! the scan the de-skew and differentiator delays align it to; the low-pass's own phase lag
//! is common to every column and is not removed (it does not change the coefficients). A
//! reading out of its linear range invalidates only the samples it can reach (the filters'
//! reach, [`conditioning::causal::CausalChain::influence`]), named in the flags of each frame
//! it touches; the filters are fed the channel's last in-range value meanwhile. Frames carry
//! the flag `chain=causal`.
//!
//! A gap (a frame whose first scan is not the next one), a change of schedule, rate or rig
//! restarts the stream: the filters start again, `edge` scans after the gap, and the output
//! frame says so in its flags. A block in which a probe left its linear range (paper step 2)
//! or the chain refused the data is published with every sample invalid and the reason in
//! its flags; nothing is silently turned into numbers.

use oilfilm_identification::conditioning::causal::{CausalChain, CausalOutput};
use oilfilm_identification::conditioning::stream::{Block, ZeroPhaseStream};
use oilfilm_identification::conditioning::{self, Conditioned, ConditioningConfig, Mechanics};
use oilfilm_identification::pipeline::{calibration_for, mechanics_of};
use oilfilm_identification::record::{RawRecord, RawUnits};
use oilfilm_msgs::{ConditionedFrame, DaqFrame, Header, BEARING_FRAME_ID};
use oilfilm_physics::config::RigConfig;
use oilfilm_physics::daq::ChannelId;
use oilfilm_physics::daq::CHANNEL_COUNT;
use serde::{Deserialize, Serialize};

use crate::error::NodeError;
use crate::node::{skipped, Connect, Input, Node, Output, Start, Turn};
use crate::params::{NodeParams, Rule, Spec};
use crate::stamp::Stamp;
use crate::topics;

/// The conditioner node's parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConditionerParams {
    /// Rig file (TOML); empty: the built-in Zhou et al. (2004) rig. Its calibration converts
    /// volts, its housing mass and exciter angles enter eq. 2.
    pub rig: String,
    /// Low-pass cutoff, Hz. Set it to about 1.5 x the highest excitation line: every hertz
    /// above lets differentiated probe noise bias the coefficients (errors in variables).
    pub lowpass_cutoff_hz: f64,
    pub lowpass_order: i64,
    pub differentiator_half_length: i64,
    /// Remove the multiplex skew (false only to demonstrate what skew does).
    pub deskew: bool,
    pub deskew_taps: i64,
    /// Samples per conditioned frame.
    pub block_scans: i64,
    /// `zero_phase` (forward-backward low-pass, centred filters: a block waits for the
    /// filter's edge past its end) or `causal` (forward-only low-pass of order
    /// `2 x lowpass_order`, a sample out a few scans after its scan; ADR 0014). Replays
    /// must use the chain the live graph used; bags recorded before this parameter existed
    /// were conditioned `zero_phase`, the default.
    pub chain: String,
}

/// Which conditioning chain the node runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Chain {
    ZeroPhase,
    Causal,
}

impl Chain {
    pub fn name(self) -> &'static str {
        match self {
            Chain::ZeroPhase => "zero_phase",
            Chain::Causal => "causal",
        }
    }
}

impl Default for ConditionerParams {
    fn default() -> Self {
        let c = ConditioningConfig::default();
        Self {
            rig: String::new(),
            lowpass_cutoff_hz: c.lowpass_cutoff_hz,
            lowpass_order: c.lowpass_order as i64,
            differentiator_half_length: c.differentiator_half_length as i64,
            deskew: c.deskew,
            deskew_taps: c.deskew_taps as i64,
            block_scans: 1000,
            chain: Chain::ZeroPhase.name().into(),
        }
    }
}

impl NodeParams for ConditionerParams {
    fn specs() -> Vec<Spec> {
        vec![
            Spec::fixed("rig", "rig file (TOML): its calibration converts volts, its housing mass and exciter angles enter eq. 2; empty: the built-in Zhou et al. (2004) rig", Rule::Any),
            Spec::fixed("lowpass_cutoff_hz", "low-pass cutoff, Hz: about 1.5 x the highest excitation line (every hertz above lets differentiated probe noise bias the coefficients)", Rule::above(0.0, 1e6))
                .with_constraints("below the Nyquist frequency of the rig file's DAQ rate (2 500 Hz at 5 kHz)"),
            Spec::fixed("lowpass_order", "Butterworth order of the low-pass (zero_phase: run forward and back; causal: order 2 x this, forward only)", Rule::Integer { min: 1, max: conditioning::lowpass::MAX_ORDER as i64 })
                .with_constraints("causal chain: at most half the largest order"),
            Spec::fixed("differentiator_half_length", "half-length of the Savitzky-Golay derivative filters, samples", Rule::Integer { min: 2, max: 10_000 }),
            Spec::fixed("deskew", "remove the multiplexer's channel skew (false only to show what skew does: it looks like added mass)", Rule::Any),
            Spec::fixed("deskew_taps", "taps of the fractional-delay de-skew filter", Rule::Integer { min: 2, max: conditioning::deskew::MAX_TAPS as i64 }),
            Spec::fixed("block_scans", "samples per conditioned frame", Rule::Integer { min: 1, max: 1_000_000 }),
            Spec::fixed("chain", "zero_phase (forward-backward low-pass: a block waits for the filter's edge past its end) or causal (forward only, a sample out a few scans after its scan; ADR 0014); a replay must use the live graph's", Rule::OneOf(&["zero_phase", "causal"])),
        ]
    }

    fn validate(&self) -> Result<(), NodeError> {
        ConditionerParams::validate(self)
    }
}

impl ConditionerParams {
    /// The conditioning chain's settings (checked against the rate when the stream starts).
    pub fn conditioning(&self) -> Result<ConditioningConfig, NodeError> {
        let count = |name: &str, v: i64| usize::try_from(v).map_err(|_| NodeError::parameter(name, format!("must be >= 0, got {v}")));
        Ok(ConditioningConfig {
            lowpass_cutoff_hz: self.lowpass_cutoff_hz,
            lowpass_order: count("lowpass_order", self.lowpass_order)?,
            differentiator_half_length: count("differentiator_half_length", self.differentiator_half_length)?,
            deskew: self.deskew,
            deskew_taps: count("deskew_taps", self.deskew_taps)?,
        })
    }

    /// The chain named by `chain`.
    pub fn chain(&self) -> Result<Chain, NodeError> {
        match self.chain.as_str() {
            "zero_phase" => Ok(Chain::ZeroPhase),
            "causal" => Ok(Chain::Causal),
            other => Err(NodeError::parameter("chain", format!("`{other}` is not a chain (zero_phase, causal)"))),
        }
    }

    pub fn validate(&self) -> Result<(), NodeError> {
        if !(1..=1_000_000).contains(&self.block_scans) {
            return Err(NodeError::parameter("block_scans", format!("must be in 1..=1000000, got {}", self.block_scans)));
        }
        let c = self.conditioning()?;
        if self.chain()? == Chain::Causal && conditioning::causal::causal_order(&c) > conditioning::lowpass::MAX_ORDER {
            return Err(NodeError::parameter(
                "lowpass_order",
                format!(
                    "the causal chain runs order 2 x lowpass_order, at most {}: must be <= {}, got {}",
                    conditioning::lowpass::MAX_ORDER,
                    conditioning::lowpass::MAX_ORDER / 2,
                    self.lowpass_order
                ),
            ));
        }
        Ok(())
    }
}

/// The stream being conditioned.
struct Stream {
    rate_hz: f64,
    units: u8,
    channels: Vec<ChannelId>,
    offsets_s: Vec<f64>,
    rig: String,
    /// The zero-phase chain for the stream's calibration, which conditions a block the stream
    /// leaves to it as a window of `raw` (`None` for the causal chain).
    window: Option<conditioning::Chain>,
    /// Scan index of `raw.columns[*][0]`.
    first_scan: u64,
    /// The stream's first scan and its rig time: every stamp is computed from these, so
    /// rounding never accumulates.
    origin_scan: u64,
    origin_stamp: Stamp,
    /// The scans received and still needed, one column per channel in the stream's order
    /// (channels and units fixed for the stream): read by the zero-phase stream, and by the
    /// windowed conditioning of a block the stream leaves to it (`window`, in place). Scans no
    /// block needs any more are dropped in batches (see [`ConditionerCore::condition_block`]).
    raw: RawRecord,
    /// Next scan to publish.
    next_out: u64,
    edge: usize,
    /// Why the stream (re)started, for the first frame's flags.
    start_note: Option<String>,
    /// The causal chain's state (`chain: causal`); `raw` stays empty then.
    causal: Option<Box<CausalStream>>,
    /// The zero-phase chain as a stream (ADR 0019), when it can run (`deskew` on, all ten
    /// channels); a block it cannot condition is conditioned as a window of `raw`.
    zero_phase: Option<Box<ZeroPhaseStream>>,
}

/// A stream through the causal chain.
struct CausalStream {
    chain: CausalChain,
    /// Samples out of the chain, not yet published.
    pending: CausalOutput,
    /// Whether the samples before the first block (see `push`) are dropped.
    aligned: bool,
    /// One frame's scans, the stream's channels only, in their order (the order of the
    /// frame's channels the chain uses: a change of it restarts the stream).
    rows: Vec<f64>,
}

impl Stream {
    fn end_scan(&self) -> u64 {
        match &self.causal {
            Some(c) => self.origin_scan + c.chain.scans(),
            None => self.first_scan + self.raw.len() as u64,
        }
    }
}

/// The channels of a frame the chain uses: position in the frame, channel.
type KeptChannels = Vec<(usize, ChannelId)>;

/// The conditioner's state.
pub struct ConditionerCore {
    rig: RigConfig,
    mechanics: Mechanics,
    config: ConditioningConfig,
    chain: Chain,
    block: usize,
    stream: Option<Stream>,
    work: Conditioned,
    sequence: u64,
    /// A UNITS_COUNTS frame's samples in volts (`DaqFrame::samples`), reused.
    decoded: Vec<f64>,
}

impl ConditionerCore {
    pub fn new(rig: RigConfig, params: &ConditionerParams) -> Result<Self, NodeError> {
        params.validate()?;
        // The rig's DAQ rate: a cutoff at or above its Nyquist frequency (or a filter that
        // cannot be designed there) would refuse every frame, so it is refused here.
        params.conditioning()?.validate(rig.daq.sample_rate_hz).map_err(|e| match e {
            oilfilm_identification::IdentificationError::InvalidParameter { field, reason } => {
                NodeError::parameter(field.trim_start_matches("conditioning."), format!("{reason} (the rig file's DAQ rate)"))
            }
            other => NodeError::Identification(other),
        })?;
        Ok(Self {
            mechanics: mechanics_of(&rig),
            rig,
            config: params.conditioning()?,
            chain: params.chain()?,
            block: params.block_scans as usize,
            stream: None,
            work: Conditioned::default(),
            sequence: 0,
            decoded: Vec::new(),
        })
    }

    /// Scans each conditioned block needs on either side (once a stream has started); for
    /// the causal chain, the scans a sample waits for after its own.
    pub fn edge_scans(&self) -> Option<usize> {
        self.stream.as_ref().map(|s| s.edge)
    }

    /// The chain this conditioner runs.
    pub fn chain(&self) -> Chain {
        self.chain
    }

    /// Takes one DAQ frame; returns the conditioned frames it completes. `Err` for a frame
    /// that cannot be used (it is skipped; the stream goes on).
    pub fn push(&mut self, frame: &DaqFrame) -> Result<Vec<ConditionedFrame>, NodeError> {
        let mut decoded = std::mem::take(&mut self.decoded);
        let out = self.push_samples(frame, &mut decoded);
        self.decoded = decoded;
        out
    }

    fn push_samples(&mut self, frame: &DaqFrame, decoded: &mut Vec<f64>) -> Result<Vec<ConditionedFrame>, NodeError> {
        let kept = self.check(frame)?;
        let n_scans = frame.scan_count as usize;
        let channels: Vec<ChannelId> = kept.iter().map(|(_, id)| *id).collect();
        let offsets: Vec<f64> = kept.iter().map(|(c, _)| frame.channel_offsets_s[*c]).collect();
        let restart = match &self.stream {
            None => Some("stream started".to_string()),
            Some(s)
                if s.rate_hz != frame.sample_rate_hz || s.channels != channels || s.offsets_s != offsets || s.units != frame.units || s.rig != frame.rig =>
            {
                Some(format!("stream restarted at scan {}: the DAQ's rate, schedule, units or rig changed", frame.first_scan))
            }
            Some(s) if s.end_scan() != frame.first_scan => Some(format!(
                "stream restarted at scan {}: {} (expected scan {})",
                frame.first_scan,
                if frame.first_scan > s.end_scan() {
                    format!("{} scans missing", frame.first_scan - s.end_scan())
                } else {
                    "scans repeated or out of order".to_string()
                },
                s.end_scan()
            )),
            Some(_) => None,
        };
        if let Some(note) = restart {
            let ignored: Vec<&str> = frame.channel_names.iter().filter(|n| ChannelId::parse(n).is_err()).map(String::as_str).collect();
            let note = if ignored.is_empty() { note } else { format!("{note}; channels not used by the chain ignored: {}", ignored.join(", ")) };
            self.start_stream(frame, channels, offsets, note)?;
        }
        let Some(stream) = self.stream.as_mut() else { return Ok(Vec::new()) };
        let width = frame.channel_names.len();
        if let Some(c) = stream.causal.as_mut() {
            let bad = |reason: String| NodeError::BadMessage { topic: topics::DAQ_FRAMES.name.into(), sequence: frame.sequence, reason };
            let samples = frame.samples(decoded).map_err(bad)?;
            // The chain reads rows of the stream's channels in the frame's order (`kept` is
            // in frame order): when the frame holds only channels the chain uses (a DAQ
            // sending the paper's ten, in any order), its samples (`scan_count` whole rows,
            // checked) are such rows already; otherwise the kept readings are gathered.
            let rows = if kept.len() == width {
                samples
            } else {
                c.rows.clear();
                for k in 0..n_scans {
                    let row = &samples[k * width..(k + 1) * width];
                    c.rows.extend(kept.iter().map(|&(col, _)| row[col]));
                }
                &c.rows
            };
            // Whole rows of the stream's channels by construction: this cannot fail.
            c.chain.push(rows, &mut c.pending)?;
            if !c.aligned && !c.pending.is_empty() {
                // The first block starts at a multiple of `block_scans` of the DAQ's scan
                // numbering, as the estimator's windows do (`[k hop, k hop + window)`): a
                // window ending on a block's end is then out as soon as its last sample is.
                let first = stream.origin_scan + c.pending.first_index;
                let skip = ((self.block as u64 - first % self.block as u64) % self.block as u64) as usize;
                if c.pending.len() >= skip {
                    c.pending.consume(skip);
                    c.aligned = true;
                } else {
                    // Not yet: keep the violations, drop the samples (they precede the first block).
                    let n = c.pending.len();
                    c.pending.consume(n);
                }
            }
            let mut out = Vec::new();
            while self.stream.as_ref().and_then(|s| s.causal.as_ref()).is_some_and(|c| c.pending.len() >= self.block) {
                out.push(self.causal_block());
            }
            return Ok(out);
        }
        // Straight from the frame's counts or values into the stream's columns (checked by
        // `check`: the picks are the frame's channels, the samples consistent).
        let picks: Vec<usize> = kept.iter().map(|(c, _)| *c).collect();
        frame.extend_columns(&picks, &mut stream.raw.columns).map_err(|reason| NodeError::BadMessage {
            topic: topics::DAQ_FRAMES.name.into(),
            sequence: frame.sequence,
            reason,
        })?;
        if let Some(zp) = stream.zero_phase.as_mut() {
            // The stream's record holds every scan from `first_needed` on (see `condition_block`).
            zp.advance(&stream.raw, (stream.first_scan - stream.origin_scan) as usize)?;
        }
        let mut out = Vec::new();
        while let Some(stream) = self.stream.as_ref() {
            if stream.end_scan() < stream.next_out + (self.block + stream.edge) as u64 {
                break;
            }
            out.push(self.condition_block());
        }
        Ok(out)
    }

    /// The channels the chain uses (position in the frame, id), once the frame's samples are
    /// checked consistent (`scan_count` x channels of them, in the units it states), or why
    /// the frame cannot be used.
    fn check(&self, frame: &DaqFrame) -> Result<KeptChannels, NodeError> {
        let bad = |reason: String| NodeError::BadMessage { topic: topics::DAQ_FRAMES.name.into(), sequence: frame.sequence, reason };
        if !(frame.sample_rate_hz.is_finite() && frame.sample_rate_hz > 0.0) {
            return Err(bad(format!("sample_rate_hz must be finite and > 0, got {}", frame.sample_rate_hz)));
        }
        let width = frame.channel_names.len();
        if frame.channel_offsets_s.len() != width {
            return Err(bad(format!("{} channel_offsets_s for {width} channel_names", frame.channel_offsets_s.len())));
        }
        frame.check_samples().map_err(bad)?;
        if frame.rig != self.rig.name {
            return Err(bad(format!("frame from rig `{}`, but this conditioner has the calibration of rig `{}` (parameter `rig`)", frame.rig, self.rig.name)));
        }
        // Channels the chain does not use (a DAQ may carry more) are ignored, not refused;
        // a channel the chain needs but the frame lacks is refused by the chain with its name.
        let mut channels = Vec::new();
        for (c, name) in frame.channel_names.iter().enumerate() {
            if let Ok(id) = ChannelId::parse(name) {
                if channels.iter().any(|(_, k)| *k == id) {
                    return Err(bad(format!("channel `{name}` appears twice")));
                }
                channels.push((c, id));
            }
        }
        Ok(channels)
    }

    fn start_stream(&mut self, frame: &DaqFrame, channels: Vec<ChannelId>, offsets_s: Vec<f64>, note: String) -> Result<(), NodeError> {
        let probe = RawRecord {
            sample_rate_hz: frame.sample_rate_hz,
            start_time_s: 0.0,
            channels: channels.clone(),
            units: RawUnits::Volts,
            columns: vec![Vec::new(); channels.len()],
        };
        let calibration = calibration_for(&self.rig, &probe, &offsets_s)?;
        let units = if frame.units == DaqFrame::UNITS_SI { RawUnits::Si } else { RawUnits::Volts };
        let (mut zero_phase, mut window) = (None, None);
        let (edge, causal) = match self.chain {
            Chain::ZeroPhase => {
                // A stream that cannot be set up (a channel missing, say) leaves every block
                // to the windowed conditioning, which names what is wrong in each block.
                let chain = conditioning::Chain::new(&calibration, &self.mechanics, &self.config, frame.sample_rate_hz)?;
                zero_phase = ZeroPhaseStream::new(chain.clone(), &channels, units).ok().map(Box::new);
                let edge = chain.edge();
                window = Some(chain);
                (edge, None)
            }
            Chain::Causal => {
                let mut columns = [usize::MAX; CHANNEL_COUNT];
                for (k, c) in channels.iter().enumerate() {
                    columns[c.index()] = k;
                }
                if let Some(missing) = ChannelId::ALL.iter().find(|c| columns[c.index()] == usize::MAX) {
                    return Err(NodeError::BadMessage {
                        topic: topics::DAQ_FRAMES.name.into(),
                        sequence: frame.sequence,
                        reason: format!("channel `{missing}` missing: conditioning needs all ten"),
                    });
                }
                let chain = CausalChain::new(&columns, channels.len(), units, frame.sample_rate_hz, &calibration, &self.mechanics, &self.config)?;
                (chain.delays().delay_scans(), Some(Box::new(CausalStream { chain, pending: CausalOutput::default(), aligned: false, rows: Vec::new() })))
            }
        };
        // A restart before the previous stream published anything keeps its note: every gap
        // is reported, even when gaps come closer together than a block.
        let note = match self.stream.as_mut().and_then(|s| s.start_note.take()) {
            Some(earlier) => format!("{earlier}; {note}"),
            None => note,
        };
        self.stream = Some(Stream {
            rate_hz: frame.sample_rate_hz,
            units: frame.units,
            offsets_s,
            rig: frame.rig.clone(),
            window,
            first_scan: frame.first_scan,
            origin_scan: frame.first_scan,
            origin_stamp: Stamp::from_time(&frame.header.stamp),
            raw: RawRecord {
                sample_rate_hz: frame.sample_rate_hz,
                start_time_s: 0.0,
                channels: channels.clone(),
                units,
                columns: vec![Vec::new(); channels.len()],
            },
            channels,
            next_out: frame.first_scan + edge as u64,
            edge,
            start_note: Some(note),
            causal,
            zero_phase,
        });
        Ok(())
    }

    /// Publishes the first `block` samples the causal chain has out (the caller checked
    /// they are there).
    /// A conditioned frame's header, numbering and the flags both chains set (an associated
    /// function: the callers hold the stream borrowed).
    fn next_frame(sequence: &mut u64, config: &ConditioningConfig, stamp: Stamp, first_sample: u64, rate_hz: f64) -> ConditionedFrame {
        let mut frame = ConditionedFrame {
            header: Header { stamp: stamp.to_time(), frame_id: BEARING_FRAME_ID.into() },
            sequence: *sequence,
            first_sample,
            sample_rate_hz: rate_hz,
            ..Default::default()
        };
        *sequence += 1;
        frame.flags.push(format!("lowpass_hz={}", config.lowpass_cutoff_hz));
        if config.deskew {
            frame.flags.push("deskewed".into());
        }
        frame
    }

    fn causal_block(&mut self) -> ConditionedFrame {
        let block = self.block;
        let Some(s) = self.stream.as_mut() else { return ConditionedFrame::default() };
        let Some(c) = s.causal.as_mut() else { return ConditionedFrame::default() };
        let p = &mut c.pending;
        let first = s.origin_scan + p.first_index;
        let stamp = s.origin_stamp.after_samples(p.first_index as i64, s.rate_hz);
        let mut frame = Self::next_frame(&mut self.sequence, &self.config, stamp, first, s.rate_hz);
        frame.flags.push("chain=causal".into());
        if let Some(note) = s.start_note.take() {
            frame.flags.push(note);
        }
        let cut = |v: &[f64]| v[..block].to_vec();
        frame.x_m = cut(&p.x_m);
        frame.y_m = cut(&p.y_m);
        frame.x_dot_m_s = cut(&p.vx_m_s);
        frame.y_dot_m_s = cut(&p.vy_m_s);
        frame.x_ddot_m_s2 = cut(&p.ax_m_s2);
        frame.y_ddot_m_s2 = cut(&p.ay_m_s2);
        frame.fx_n = cut(&p.fx_n);
        frame.fy_n = cut(&p.fy_n);
        frame.bearing_temperature_degc = p.temperature_c[..block].iter().sum::<f64>() / block as f64;
        frame.valid = p.valid[..block].to_vec();
        // The violations that reach this block, named with their scan in the stream; those
        // that reach no later block are dropped.
        let here = p.first_index..p.first_index + block as u64;
        let chain = &c.chain;
        for v in &p.violations {
            let reach = chain.influence(v);
            if reach.start < here.end && here.start < reach.end {
                let mut named = v.clone();
                named.index = (s.origin_scan + v.index as u64) as usize;
                frame.flags.push(format!("rejected (Zhou et al. step 2): {named}"));
            }
        }
        p.violations.retain(|v| chain.influence(v).end > here.end);
        p.consume(block);
        frame
    }

    /// Conditions the block at `next_out` (the caller checked the scans are there): by the
    /// zero-phase stream, or as a window of the stream's record when the stream cannot (a
    /// reading it cannot use in the block's window, or no stream).
    fn condition_block(&mut self) -> ConditionedFrame {
        let block = self.block;
        // Checked by the caller.
        let Some(s) = self.stream.as_mut() else { return ConditionedFrame::default() };
        let offset = (s.first_scan - s.origin_scan) as usize;
        let start = (s.next_out - s.origin_scan) as usize;
        let stamp = s.origin_stamp.after_samples((s.next_out - s.origin_scan) as i64, s.rate_hz);
        let mut frame = Self::next_frame(&mut self.sequence, &self.config, stamp, s.next_out, s.rate_hz);
        if let Some(note) = s.start_note.take() {
            frame.flags.push(note);
        }
        let edge = s.edge;
        let streamed = match s.zero_phase.as_mut() {
            Some(zp) => zp.block(start, block, &s.raw, offset).transpose(),
            None => None,
        };
        let outcome = streamed.unwrap_or_else(|| {
            // The record holds the window (`start >= edge`, and the drop below keeps `edge`
            // scans before `next_out`); should it not, the window is refused, not sliced.
            let Some(begin) = (start - edge).checked_sub(offset) else {
                return Err(oilfilm_identification::IdentificationError::BadInput {
                    what: "window".into(),
                    reason: format!("scans from {} needed, the record starts at {offset}", start - edge),
                });
            };
            let Some(chain) = s.window.as_ref() else {
                return Err(oilfilm_identification::IdentificationError::invalid("chain", "the causal chain conditions no window"));
            };
            chain.condition_window_into(&s.raw, begin..begin + block + 2 * edge, &mut self.work).map(|()| {
                let w = &self.work;
                let r = edge..edge + block;
                if w.valid != r {
                    frame.flags.push(format!("internal: chain valid range {:?}, expected {r:?}", w.valid));
                }
                let cut = |v: &[f64]| v[r.clone()].to_vec();
                Block {
                    x_m: cut(&w.x_m),
                    y_m: cut(&w.y_m),
                    vx_m_s: cut(&w.vx_m_s),
                    vy_m_s: cut(&w.vy_m_s),
                    ax_m_s2: cut(&w.ax_m_s2),
                    ay_m_s2: cut(&w.ay_m_s2),
                    fx_n: cut(&w.fx_n),
                    fy_n: cut(&w.fy_n),
                    temperature_c: cut(&w.temperature_c),
                    range_violations: w.range_violations.clone(),
                }
            })
        });
        match outcome {
            Ok(b) => {
                frame.bearing_temperature_degc = b.temperature_c.iter().sum::<f64>() / block as f64;
                frame.x_m = b.x_m;
                frame.y_m = b.y_m;
                frame.x_dot_m_s = b.vx_m_s;
                frame.y_dot_m_s = b.vy_m_s;
                frame.x_ddot_m_s2 = b.ax_m_s2;
                frame.y_ddot_m_s2 = b.ay_m_s2;
                frame.fx_n = b.fx_n;
                frame.fy_n = b.fy_n;
                frame.valid = vec![b.range_violations.is_empty(); block];
                for v in &b.range_violations {
                    frame.flags.push(format!("rejected (Zhou et al. step 2): {v}"));
                }
            }
            Err(e) => {
                let nan = vec![f64::NAN; block];
                frame.x_m = nan.clone();
                frame.y_m = nan.clone();
                frame.x_dot_m_s = nan.clone();
                frame.y_dot_m_s = nan.clone();
                frame.x_ddot_m_s2 = nan.clone();
                frame.y_ddot_m_s2 = nan.clone();
                frame.fx_n = nan.clone();
                frame.fy_n = nan;
                frame.bearing_temperature_degc = f64::NAN;
                frame.valid = vec![false; block];
                frame.flags.push(format!("rejected: {e}"));
            }
        }
        s.next_out += block as u64;
        // The next block needs `edge` scans before it, and the zero-phase stream the scans
        // its de-skew reaches back to; those before them are dropped once they are at least
        // four times as many as the scans kept (a move of the kept scans every few blocks,
        // not at every block; the windows conditioned are the same).
        let mut keep_from = (s.next_out - s.first_scan) as usize - edge;
        if let Some(zp) = s.zero_phase.as_mut() {
            zp.release_before((s.next_out - s.origin_scan) as usize);
            keep_from = keep_from.min(zp.first_needed().saturating_sub(offset));
        }
        if keep_from >= 4 * (s.raw.len() - keep_from) {
            for c in &mut s.raw.columns {
                c.drain(..keep_from);
            }
            s.first_scan += keep_from as u64;
        }
        frame
    }
}

/// The conditioner node: DAQ frames in, conditioned frames out.
pub struct Conditioner {
    core: ConditionerCore,
}

pub struct ConditionerPorts<'a> {
    pub frames: Input<'a, DaqFrame>,
    pub conditioned: Output<'a, ConditionedFrame>,
}

impl Conditioner {
    pub fn core(&self) -> &ConditionerCore {
        &self.core
    }
}

impl Node for Conditioner {
    const NAME: &'static str = "conditioner";
    type Params = ConditionerParams;
    type Ports<'a> = ConditionerPorts<'a>;

    fn new(params: &ConditionerParams, start: &Start) -> Result<Self, NodeError> {
        Ok(Self { core: ConditionerCore::new((start.rig)(&params.rig)?, params)? })
    }

    fn connect<C: Connect>(&self, c: &mut C) -> Result<ConditionerPorts<'static>, NodeError> {
        Ok(ConditionerPorts { frames: c.input(&topics::DAQ_FRAMES)?, conditioned: c.output(&topics::CONDITIONED)? })
    }

    fn turn(&mut self, _now: Stamp, ports: &mut ConditionerPorts<'_>) -> Result<Turn, NodeError> {
        let mut turn = Turn::default();
        while let Some(frame) = ports.frames.receive()? {
            turn.handled += 1;
            match self.core.push(&frame) {
                Ok(out) => {
                    for c in out {
                        ports.conditioned.publish(c)?;
                        turn.handled += 1;
                    }
                }
                Err(e) => skipped(Self::NAME, &e),
            }
        }
        Ok(turn)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daq::frames_of_scans;
    use oilfilm_identification::excitation::ExcitationPlan;
    use oilfilm_identification::simulate::{self, SimulateOptions};

    /// A frame's samples as volts in another channel order (`order[k]`: the frame's column
    /// that goes to column `k`).
    fn reordered(frame: &DaqFrame, order: &[usize]) -> DaqFrame {
        let mut buf = Vec::new();
        let samples = frame.samples(&mut buf).expect("the node's frames are consistent").to_vec();
        let width = frame.channel_names.len();
        let pick = |v: &[String]| order.iter().map(|&c| v[c].clone()).collect::<Vec<_>>();
        DaqFrame {
            units: DaqFrame::UNITS_VOLTS,
            channel_names: pick(&frame.channel_names),
            channel_units: pick(&frame.channel_units),
            channel_offsets_s: order.iter().map(|&c| frame.channel_offsets_s[c]).collect(),
            values: samples.chunks_exact(width).flat_map(|row| order.iter().map(move |&c| row[c])).collect(),
            volts_per_count: Vec::new(),
            counts: Vec::new(),
            ..frame.clone()
        }
    }

    /// The conditioned samples of every frame, as bits (the flags differ: a frame with
    /// channels the chain does not use says so).
    fn conditioned_bits(rig: &RigConfig, chain: &str, frames: &[DaqFrame]) -> Vec<Vec<u64>> {
        let params = ConditionerParams { lowpass_cutoff_hz: 55.5, block_scans: 500, chain: chain.into(), ..ConditionerParams::default() };
        let mut core = ConditionerCore::new(rig.clone(), &params).expect("valid params");
        let mut out = Vec::new();
        for f in frames {
            for c in core.push(f).expect("a consistent frame") {
                let columns = [&c.x_m, &c.y_m, &c.x_dot_m_s, &c.y_dot_m_s, &c.x_ddot_m_s2, &c.y_ddot_m_s2, &c.fx_n, &c.fy_n];
                let mut bits: Vec<u64> = columns.iter().flat_map(|v| v.iter().map(|x| x.to_bits())).collect();
                bits.extend(c.valid.iter().map(|&v| u64::from(v)));
                bits.push(c.first_sample);
                out.push(bits);
            }
        }
        out
    }

    /// The causal chain reads a frame of only its ten channels straight from the frame (in
    /// whatever order: its column map follows the frame); a frame with other channels too is
    /// gathered first. Every way gives the same conditioned samples, bit for bit, on both
    /// chains.
    #[test]
    fn frames_with_extra_or_reordered_channels_condition_to_the_same_bits() {
        let rig = RigConfig::zhou2004().expect("built-in rig");
        let rec = simulate::simulate(&rig, &ExcitationPlan::two_tone(23.0, 37.0, 100.0), 1.5, SimulateOptions::default(), &mut |_| {}).expect("simulation");
        let ten = rig.daq.calibration().scan_order().len();
        let plain = frames_of_scans(&rig, &rec.scans, 250, ten, Stamp(0)).expect("frames");
        let with_aux = frames_of_scans(&rig, &rec.scans, 250, ten + 2, Stamp(0)).expect("frames");
        let reversed: Vec<DaqFrame> = plain.iter().map(|f| reordered(f, &(0..ten).rev().collect::<Vec<_>>())).collect();
        assert_eq!(plain[0].units, DaqFrame::UNITS_COUNTS, "the simulated card sends counts");
        for chain in ["causal", "zero_phase"] {
            let reference = conditioned_bits(&rig, chain, &plain);
            assert!(reference.len() >= 8, "{chain}: {} conditioned frames", reference.len());
            assert!(conditioned_bits(&rig, chain, &with_aux) == reference, "{chain}: two aux channels appended changed the output");
            assert!(conditioned_bits(&rig, chain, &reversed) == reference, "{chain}: channels in reverse order changed the output");
        }
    }
}
