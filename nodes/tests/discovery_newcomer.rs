//! A participant that joins late (`ros2 ... --no-daemon`, a fresh rclpy process) is told
//! again which readers and writers the node has, soon after it joined.
//!
//! ros2-client announces the node without the writers made outside it (the player's raw
//! ones, the exciter's acknowledged one), from a writer whose stored announcement every
//! newcomer receives; our announcer's stored one lists them. A newcomer that takes
//! ros2-client's last would name no node for those writers until the next scheduled repeat,
//! seconds away (`ros2 topic info -v --no-daemon` showed `_NODE_NAME_UNKNOWN_` every time).
//! So the announcer answers a newly matched reader with a fresh announcement.
//!
//! The proof: a reader that joins between two scheduled repeats (the fourth and the fifth)
//! receives, within 1.5 s, an announcement written after it joined, and it lists the node's
//! raw writer.

use std::time::{Duration, Instant};

use oilfilm_graph::params::NodeArgs;
use oilfilm_graph::topics::TopicQos;
use oilfilm_nodes::dds::{qos_from, ros_discovery_topic, RosNode};
use ros2_client::dds::rustdds::{
    policy::{Durability, History},
    DomainParticipant, QosPolicyBuilder, Timestamp,
};
use ros2_client::entities_info::ParticipantEntitiesInfo;

#[test]
fn a_reader_that_joins_late_is_told_the_nodes_writers_at_once() {
    // 20-39: no other DDS test of ours uses these domains.
    let domain = 20 + (std::process::id() % 20) as u16;
    // SAFETY of the environment: set before any DDS context of this test binary exists, and
    // this binary has this one test.
    std::env::set_var("ROS_DOMAIN_ID", domain.to_string());
    let started = Instant::now();
    let me = NodeArgs { name: "newcomer_test".into(), namespace: "/oilfilm_newcomer".into(), ..Default::default() };
    let mut node = RosNode::new(&me).expect("a node on DDS");
    let qos = qos_from(TopicQos { reliable: true, depth: 10, transient_local: false });
    let raw = node.raw_publisher("/oilfilm_newcomer/raw", "std_msgs/msg/String", qos).expect("a raw writer");
    let raw_gid = raw.gid();

    // The scheduled repeats come 0.5, 1.5, 3.5, 7.5 and 15.5 s after the start, each scaled
    // by a factor in [0.75, 1.25): none falls between 9.4 s and 11.6 s.
    std::thread::sleep(Duration::from_millis(9_500).saturating_sub(started.elapsed()));
    let participant = DomainParticipant::new(domain).expect("a second participant");
    let topic = ros_discovery_topic(&participant).expect("the ros_discovery_info topic");
    let qos =
        QosPolicyBuilder::new().durability(Durability::TransientLocal).reliable(ros2_client::dds::rustdds::Duration::ZERO).history(History::KeepAll).build();
    let mut reader = participant
        .create_subscriber(&qos)
        .expect("a subscriber")
        .create_datareader_no_key_cdr::<ParticipantEntitiesInfo>(&topic, Some(qos.clone()))
        .expect("a ros_discovery_info reader");
    let joined = Timestamp::now();
    let joined_at = Instant::now();

    let lists_raw = |info: &ParticipantEntitiesInfo| {
        info.nodes().iter().any(|n| {
            // Adding a writer it already lists changes nothing.
            let mut with = n.clone();
            with.add_writer(raw_gid);
            n.name() == "newcomer_test" && with == *n
        })
    };
    let (mut stored, mut fresh) = (0usize, None::<bool>);
    while joined_at.elapsed() < Duration::from_millis(1_500) && fresh.is_none() {
        match reader.take_next_sample() {
            Ok(Some(sample)) => {
                let written = sample.sample_info().source_timestamp();
                let info = sample.into_value();
                if !info.nodes().iter().any(|n| n.name() == "newcomer_test") {
                    continue;
                }
                if written.is_some_and(|t| t > joined) {
                    fresh = Some(lists_raw(&info));
                } else {
                    stored += 1;
                }
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => panic!("reading ros_discovery_info: {e:?}"),
        }
    }
    let waited = joined_at.elapsed();
    drop(raw);
    node.shutdown();
    assert!(started.elapsed() < Duration::from_millis(11_400), "the check ran into the next scheduled repeat ({:?} after the start)", started.elapsed());
    assert!(stored >= 1, "the stored announcements reached the newcomer ({stored})");
    assert_eq!(fresh, Some(true), "an announcement written after the reader joined, listing the raw writer, within {waited:?}");
}
