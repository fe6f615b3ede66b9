//! Offline re-analysis from a bag equals the live graph, bit for bit: the in-memory sim_rig
//! graph records every topic into a bag; the bag's DAQ frames and rig status, read back,
//! go through a fresh conditioner and estimator (the bag runner, `runner::bag::reanalyse`: the nodes the
//! binaries run) and give the very estimate bytes the live estimator published, which the
//! bag also holds.

use crate::sim_rig;

use oilfilm_bag::{Bag, OilfilmMessage, WriterOptions};
use oilfilm_graph::runner::bag::{reanalyse, reanalyse_overlapped, reanalyse_stream, Input};
use oilfilm_graph::runner::memory::{run_sim_rig, GraphParams};
use oilfilm_msgs::RosMessage;
use oilfilm_physics::config::RigConfig;

#[test]
fn estimates_from_a_bag_equal_the_live_ones_bit_for_bit() {
    let p = GraphParams::sim_rig(12.0, 25_000, 12_500).unwrap();
    let rig = RigConfig::zhou2004().unwrap();
    let (live, _) = run_sim_rig(&rig, &p).unwrap();
    assert!(live.estimates.len() >= 2, "{} estimates", live.estimates.len());

    let dir = std::env::temp_dir().join(format!("oilfilm-bag-replay-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let msgs = sim_rig::published(&live);
    sim_rig::write_bag(&dir, &msgs, WriterOptions::default()).unwrap().close().unwrap();

    let bag = Bag::open(&dir).unwrap();
    let (mut frames, mut status, mut recorded) = (Vec::new(), Vec::new(), Vec::new());
    for m in bag.messages().unwrap() {
        match m.decode_ours().unwrap() {
            OilfilmMessage::DaqFrame(f) => frames.push(f),
            OilfilmMessage::RigStatus(s) => status.push(s),
            OilfilmMessage::CoefficientEstimate(e) => recorded.push(e),
            _ => {}
        }
    }
    assert_eq!(frames.len(), live.frames.len(), "every frame is in the bag");
    let again = reanalyse(&rig, &p.conditioner, &p.estimator, &frames, &status).unwrap();
    let bytes = |v: &[oilfilm_msgs::CoefficientEstimate]| v.iter().map(oilfilm_msgs::encode).collect::<Vec<_>>();
    assert_eq!(bytes(&again.estimates), bytes(&live.estimates), "re-analysis from the bag differs from live");
    assert_eq!(bytes(&recorded), bytes(&live.estimates), "the bag's recorded estimates differ from what was published");

    // What `oilfilm identify BAG` runs: only the frames' and status' chunks read, decoded on
    // worker threads and conditioned as they arrive.
    for threads in [1, 2, 3] {
        let is_input = |_: &str, ty: &str| ty == oilfilm_msgs::DaqFrame::TYPE_NAME || ty == oilfilm_msgs::RigStatus::TYPE_NAME;
        let decode = |m: &oilfilm_bag::MessageRef| -> oilfilm_bag::Result<Input> {
            Ok(if m.type_name == oilfilm_msgs::DaqFrame::TYPE_NAME { Input::Frame(m.decode()?) } else { Input::Status(m.decode()?) })
        };
        let streamed = bag.read_topics(&is_input, &decode, threads, |inputs| reanalyse_stream(&rig, &p.conditioner, &p.estimator, inputs)).unwrap().unwrap();
        assert_eq!(bytes(&streamed.estimates), bytes(&live.estimates), "streamed re-analysis ({threads} threads) differs from live");
        assert_eq!(streamed.conditioned, again.conditioned, "conditioned frames ({threads} threads)");

        // The same as `oilfilm identify BAG` reads it (src/records.rs, `reanalyse_bag`): the
        // status chunks first, then the frames streamed through the conditioner here and the
        // estimator on a thread of its own.
        let is_status = |_: &str, ty: &str| ty == oilfilm_msgs::RigStatus::TYPE_NAME;
        let is_frame = |_: &str, ty: &str| ty == oilfilm_msgs::DaqFrame::TYPE_NAME;
        let status: Vec<oilfilm_msgs::RigStatus> = bag.read_topics(&is_status, &|m| m.decode(), threads, |s| s.collect()).unwrap();
        assert!(!status.is_empty());
        let overlapped = bag
            .read_topics(&is_frame, &|m| m.decode::<oilfilm_msgs::DaqFrame>(), threads, |frames| {
                reanalyse_overlapped(&rig, &p.conditioner, &p.estimator, status, frames)
            })
            .unwrap()
            .unwrap();
        assert_eq!(bytes(&overlapped.estimates), bytes(&live.estimates), "overlapped re-analysis ({threads} threads) differs from live");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
