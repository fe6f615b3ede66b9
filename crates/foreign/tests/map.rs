//! The channel map: a valid fixture reads as written; every kind of mistake is refused with
//! the map's key at fault.

use std::path::Path;

use oilfilm_foreign::map::{ChannelMap, Multiplexer, Rate, Speed, SpeedUnit, Temperature, Unit};
use oilfilm_foreign::ForeignError;
use oilfilm_physics::daq::ChannelId;

fn fixture() -> String {
    std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/zhou-tdms.map.toml")).unwrap()
}

fn parse(text: &str) -> Result<ChannelMap, ForeignError> {
    ChannelMap::from_toml_str(text, Path::new("m.toml"))
}

/// The error's key and message for a map, which must be refused.
fn refused(text: &str) -> (String, String) {
    match parse(text) {
        Err(ForeignError::Map { key, message, map }) => {
            assert_eq!(map, Path::new("m.toml"));
            (key, message)
        }
        other => panic!("expected a map error, got {other:?}"),
    }
}

#[test]
fn the_fixture_reads_as_written() {
    let m = parse(&fixture()).unwrap();
    assert_eq!(m.rate, Rate::From("wf_increment".into()));
    assert_eq!(m.multiplexer, Multiplexer::Sequential { channel_interval_s: 1e-5 });
    assert_eq!(m.channels.len(), 9);
    assert_eq!(m.channels[1].rig, ChannelId::ProbeAY);
    assert_eq!(m.channels[1].scaling.sign, -1.0);
    assert_eq!(m.channels[2].source.index, Some(2));
    assert_eq!(m.channels[5].unit, Unit::MilliVolt);
    assert_eq!(m.temperature, Temperature::Celsius(41.5));
    assert!(matches!(m.speed, Speed::Channel { unit: SpeedUnit::Hz, .. }));
    assert!(!m.all_volts());
    // The conversions: um to m by division (correctly rounded), a negative sign applied
    // before the unit, mV with scale and offset.
    assert_eq!(m.channels[0].convert(25.0), 25.0 / 1e6);
    assert_eq!(m.channels[1].convert(25.0), -25.0 / 1e6);
    assert_eq!(m.channels[5].convert(1000.0), (2.0 * 1000.0 - 0.5) / 1e3);
    assert_eq!(m.channels[6].convert(1.5), 1500.0);
    // An identity mapping keeps the bits, -0.0 included.
    assert_eq!(m.channels[4].convert(-0.0).to_bits(), (-0.0f64).to_bits());
}

#[test]
fn every_mistake_names_its_key() {
    let base = fixture();
    let cases: Vec<(String, &str, &str)> = vec![
        (base.replace("format = \"tdms\"", "format = \"tdms\"\ncolour = 3"), "byte", "unknown field `colour`"),
        (base.replace("rig = \"f2\"", "rig = \"f1\""), "channel[7].rig", "`f1` is mapped twice: channel[6] maps it already"),
        (base.replace("from = \"Forces/F2\"", "from = \"Forces/F1\""), "channel[7].from", "mapped twice"),
        (base.replace("rig = \"f3\"", "rig = \"f4\""), "channel[8].rig", "`f4` is not a channel of the rig"),
        (base.replace("unit = \"kN\"", "unit = \"um\""), "channel[6].unit", "`um` is not a unit of `f1`"),
        (base.replace("unit = \"kN\"", "unit = \"lbf\""), "byte", "unknown variant `lbf`"),
        (base.replace("sign = -1", "sign = 2"), "channel[1].sign", "must be 1 or -1"),
        (base.replace("scale = 2.0", "scale = 0.0"), "channel[5].scale", "non-zero"),
        (base.replace("sample_rate_from = \"wf_increment\"", "sample_rate_from = \"wf_increment\"\nsample_rate_hz = 5000"), "timing", "not both"),
        (base.replace("sample_rate_from = \"wf_increment\"", ""), "timing", "the sample rate is missing"),
        (base.replace("channel_interval_s = 1e-5", ""), "timing.channel_interval_s", "needs the time between two conversions"),
        (base.replace("multiplexer = \"sequential\"", "multiplexer = \"round robin\""), "timing.multiplexer", "expected simultaneous, sequential or offsets"),
        (base.replace("[temperature]\ncelsius = 41.5", ""), "channel", "`temperature` is not mapped"),
        (
            base.replace("rig = \"frame_x\"\nfrom = \"Frame/x\"\nunit = \"m\"", "rig = \"temperature\"\nfrom = \"Frame/x\"\nunit = \"C\""),
            "temperature",
            "mapped from a channel already",
        ),
        (base.replace("from = \"Probes\"\nindex = 2", "index = 2"), "channel[2].index", "a TDMS channel is found by from"),
        (base.replace("from = \"Tacho/speed\"", "from = \"Forces/F2\""), "speed.from", "mapped to `f2` by channel[7] already"),
        (base.replace("from = \"Tacho/speed\"\nunit = \"Hz\"", "rpm = 1500\nunit = \"Hz\""), "speed", "rpm is a number in rpm"),
    ];
    for (text, key, words) in cases {
        let (k, m) = refused(&text);
        assert!(k.starts_with(key), "key `{k}` (expected `{key}`): {m}");
        assert!(m.contains(words), "`{m}` should say `{words}`");
    }
}

#[test]
fn a_rig_channel_left_out_is_named() {
    let text = fixture().replace("[[channel]]\nrig = \"f3\"\nfrom = \"Forces/Bellows\"\nunit = \"N\"\n", "");
    let (key, message) = refused(&text);
    assert_eq!(key, "channel");
    assert!(message.contains("the rig's f3 is not mapped"), "{message}");
}

#[test]
fn csv_options_and_offsets() {
    let mut text = String::from("format = \"csv\"\n[timing]\nsample_rate_hz = 5000\nmultiplexer = \"offsets\"\n[csv]\ndelimiter = \";\"\nunits_row = true\n");
    for (k, c) in ChannelId::ALL.iter().enumerate() {
        let unit = if c.is_displacement_probe() {
            "um"
        } else if *c == ChannelId::Temperature {
            "C"
        } else {
            "N"
        };
        text.push_str(&format!("[[channel]]\nrig = \"{c}\"\nindex = {k}\nunit = \"{unit}\"\noffset_s = {k}e-5\n"));
    }
    let m = parse(&text).unwrap();
    assert_eq!((m.csv.delimiter, m.csv.units_row), (b';', true));
    assert_eq!(m.channels[3].offset_s, Some(3e-5));
    assert_eq!(m.speed, Speed::RigFile);
    let (key, message) = refused(&text.replace("offset_s = 3e-5", ""));
    assert_eq!(key, "channel[3].offset_s", "{message}");
    let (key, _) = refused(&text.replace("index = 4", "index = 4\nfrom = \"x\""));
    assert_eq!(key, "channel[4]");
}
