//! `oilfilm import FILE [--map MAP] -o BAG`: a record as the rosbag2 bag the recorder would
//! have made of the DAQ node replaying it: `daq/frames` and `rig/status` under `/oilfilm`,
//! with the QoS the recorder records, each message logged at its own stamp (the
//! acquisition's clock: an import has no receive time). A TDMS, .mat or CSV record goes
//! through its channel map (the DAQ node's `foreign` source); our ASCII format through the
//! `ascii` source (bad rows skipped with a warning, as the node does).
//!
//! The bag is written under a temporary name beside `BAG` and renamed when complete: a
//! record that turns out unreadable half-way leaves nothing behind.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use oilfilm_graph::daq::DaqParams;
use oilfilm_graph::foreign::ForeignSource;
use oilfilm_graph::lines::{run_ascii_source, ReplayPace};
use oilfilm_graph::ports::RawCdr;
use oilfilm_graph::recorder::{select_topics, RecorderCore, RecorderParams};
use oilfilm_graph::replay::ReplayCore;
use oilfilm_graph::stamp::Stamp;
use oilfilm_msgs::{DaqFrame, RigStatus};

use crate::RigSource;

#[derive(Debug, clap::Args)]
pub struct ImportArgs {
    /// The record: TDMS, .mat or CSV (with --map), or our ASCII format (plain or gzip).
    file: PathBuf,
    /// Channel map (TOML) of a TDMS, .mat or CSV record (docs/manual/foreign-records.md).
    #[arg(long, value_name = "MAP")]
    map: Option<PathBuf>,
    /// The bag directory to write (it must not exist).
    #[arg(long, short, value_name = "BAG")]
    output: PathBuf,
    #[command(flatten)]
    source: RigSource,
    /// Scans per DAQ frame (the DAQ node's `block_scans`).
    #[arg(long, default_value_t = 500)]
    block_scans: i64,
    /// Shaft speed the rig status states, rpm (default: the map's or the record's, else the
    /// rig file's).
    #[arg(long)]
    speed_rpm: Option<f64>,
    /// Chunk compression: zstd, lz4 or none.
    #[arg(long, default_value = "zstd")]
    compression: String,
}

/// What an import wrote.
struct Written {
    frames: u64,
    status: u64,
    scans: u64,
    first: Option<DaqFrame>,
    last_status: Option<RigStatus>,
}

struct Sink {
    core: RecorderCore,
    written: Written,
}

impl Sink {
    fn put(&mut self, frame: DaqFrame, status: RigStatus) -> Result<()> {
        let log = |stamp: &oilfilm_msgs::Time| Stamp::from_time(stamp);
        self.core.record(0, log(&frame.header.stamp), &RawCdr(oilfilm_msgs::cdr::encode(&frame)))?;
        self.core.record(1, log(&status.header.stamp), &RawCdr(oilfilm_msgs::cdr::encode(&status)))?;
        self.written.frames += 1;
        self.written.status += 1;
        self.written.scans += u64::from(frame.scan_count);
        if self.written.first.is_none() {
            self.written.first = Some(DaqFrame { values: Vec::new(), counts: Vec::new(), ..frame });
        }
        self.written.last_status = Some(status);
        Ok(())
    }
}

pub fn run(args: &ImportArgs) -> Result<()> {
    let name = args.file.display().to_string();
    if args.output.exists() {
        bail!("{}: already exists; an import writes a new bag directory", args.output.display());
    }
    let parent = args.output.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
    let stem = args.output.file_name().map_or("bag".into(), |n| n.to_string_lossy().into_owned());
    // Written under its own name in a hidden directory beside it (the bag's files carry the
    // directory's name), then moved into place.
    let staging = parent.join(format!(".{stem}.importing-{}", std::process::id()));
    let partial = staging.join(&stem);
    let rig = args.source.load()?;
    let daq = DaqParams {
        source: if args.map.is_some() { "foreign".into() } else { "ascii".into() },
        file: name.clone(),
        map: args.map.as_ref().map(|m| m.display().to_string()).unwrap_or_default(),
        block_scans: args.block_scans,
        speed_rpm: args.speed_rpm.unwrap_or(0.0),
        rate_factor: 0.0,
        ..DaqParams::default()
    };
    daq.validate()?;
    // The source first: a bad map or file is refused before any directory is made.
    let mut foreign = match &args.map {
        Some(map) => Some(ForeignSource::open(&args.file, map, &rig, &daq)?),
        None => None,
    };
    std::fs::create_dir_all(&staging).with_context(|| format!("cannot create {}", staging.display()))?;
    let recorder =
        RecorderParams { output: partial.display().to_string(), compression: args.compression.clone(), status_period_s: 0.0, ..RecorderParams::default() };
    let writer = oilfilm_bag::BagWriter::create(&partial, recorder.writer_options()?)?;
    let topics = select_topics(oilfilm_graph::topics::NAMESPACE, &["daq/frames".into(), "rig/status".into()])?;
    let mut sink = Sink { core: RecorderCore::new(writer, topics)?, written: Written { frames: 0, status: 0, scans: 0, first: None, last_status: None } };
    let result = (|| -> Result<()> {
        match &mut foreign {
            Some(source) => {
                while let Some((frame, status)) = source.next_frame()? {
                    sink.put(frame, status)?;
                }
            }
            None => {
                let mut core = ReplayCore::new(&rig, &daq, "ascii import", &name)?;
                let file = std::fs::File::open(&args.file).with_context(|| format!("cannot read {name}"))?;
                let mut reader = BufReader::with_capacity(1 << 16, file);
                let gzip = reader.fill_buf().map(|b| b.starts_with(&[0x1f, 0x8b])).unwrap_or(false);
                let stream: Box<dyn BufRead> = if gzip { Box::new(BufReader::new(flate2::bufread::MultiGzDecoder::new(reader))) } else { Box::new(reader) };
                let mut failed = None;
                run_ascii_source(stream, &mut core, &ReplayPace { rate_factor: 0.0, duration_s: 0.0 }, &|| false, &mut |out| {
                    if let Some(e) = &out.bad_row {
                        eprintln!("warning: {e} (skipped, as the DAQ node skips it)");
                    }
                    for (frame, status) in out.frames {
                        if let Err(e) = sink.put(frame, status) {
                            failed = Some(e);
                            return Err(oilfilm_graph::NodeError::Closed("the bag".into()));
                        }
                    }
                    Ok(())
                })
                .map_err(|e| failed.take().unwrap_or_else(|| e.into()))?;
            }
        }
        if sink.written.frames == 0 {
            bail!("{name}: the record holds no scans; no bag is written");
        }
        Ok(())
    })();
    let Sink { core, written } = sink;
    let closed = core.close();
    if let Err(e) = result.and(closed.map(|_| ()).map_err(anyhow::Error::from)) {
        let _ = std::fs::remove_dir_all(&staging);
        return Err(e.context(format!("{name}: nothing was written to {}", args.output.display())));
    }
    std::fs::rename(&partial, &args.output).with_context(|| format!("cannot move {} to {}", partial.display(), args.output.display()))?;
    let _ = std::fs::remove_dir(&staging);
    let f = written.first.as_ref();
    let rate = f.map_or(0.0, |f| f.sample_rate_hz);
    println!(
        "{name} -> {}: {} DAQ frames ({} scans, {:.3} s at {rate} Hz, {} in {}), {} rig status messages{}",
        args.output.display(),
        written.frames,
        written.scans,
        written.scans as f64 / rate,
        f.map_or(String::new(), |f| f.channel_names.join(" ")),
        f.map_or("", |f| if f.units == DaqFrame::UNITS_VOLTS { "volts" } else { "SI units" }),
        written.status,
        written.last_status.map(|s| format!("; {}", s.message)).unwrap_or_default()
    );
    Ok(())
}
