//! Our nodes keep announcing themselves on `ros_discovery_info` (the ROS graph's node list,
//! behind `ros2 node list` and rclpy's `get_node_names`), so an announcement lost in a busy
//! reader's keep-last-1 queue is sent again (see `Announcer` in `nodes/src/dds.rs`).
//!
//! The proof: a reader that joins a second after the node started keeps receiving the
//! node's participant info after what the writers held for it has arrived: at least twice
//! more within the announcer's first 16 s. Without the re-announcement nothing new would
//! come (the node creates no entity after its start).

use std::time::{Duration, Instant};

use oilfilm_graph::params::NodeArgs;
use oilfilm_nodes::dds::{ros_discovery_topic, RosNode};
use ros2_client::dds::rustdds::{
    policy::{Durability, History},
    DomainParticipant, QosPolicyBuilder,
};
use ros2_client::entities_info::{NodeEntitiesInfo, ParticipantEntitiesInfo};
use ros2_client::NodeName;

#[test]
fn a_late_volatile_reader_hears_the_node_announced_again() {
    // 1-19: no other DDS test of ours uses these domains.
    let domain = 1 + (std::process::id() % 19) as u16;
    // SAFETY of the environment: set before any DDS context of this test binary exists, and
    // this binary has this one test.
    std::env::set_var("ROS_DOMAIN_ID", domain.to_string());
    let me = NodeArgs { name: "announced".into(), namespace: "/oilfilm_announce".into(), ..Default::default() };
    let node = RosNode::new(&me).expect("a node on DDS");
    std::thread::sleep(Duration::from_secs(1));

    let participant = DomainParticipant::new(domain).expect("a second participant");
    let topic = ros_discovery_topic(&participant).expect("the ros_discovery_info topic");
    let qos = QosPolicyBuilder::new().durability(Durability::Volatile).reliable(ros2_client::dds::rustdds::Duration::ZERO).history(History::KeepAll).build();
    let mut reader = participant
        .create_subscriber(&qos)
        .expect("a subscriber")
        .create_datareader_no_key_cdr::<ParticipantEntitiesInfo>(&topic, Some(qos.clone()))
        .expect("a ros_discovery_info reader");

    let n_name = NodeName::new("/oilfilm_announce", "announced").expect("a valid node name");
    let joined = Instant::now();
    // What the writers hold for a newcomer arrives in the first moments (rustdds sends its
    // history even to a volatile reader, and the participant has two writers), so only the
    // samples that arrive after 2 s count: those are new announcements.
    let mut heard_late = 0usize;
    let mut listed_with_entities = false;
    while joined.elapsed() < Duration::from_secs(17) && heard_late < 2 {
        match reader.take_next_sample() {
            Ok(Some(sample)) => {
                let info = sample.into_value();
                let ours = info.nodes().iter().find(|n| n.name() == "announced" && n.namespace() == "/oilfilm_announce");
                if let Some(n) = ours {
                    if joined.elapsed() > Duration::from_secs(2) {
                        heard_late += 1;
                        // The node's writers (rosout, parameter events, ...) are listed: a
                        // repeat is the full info, not an empty shell.
                        listed_with_entities |= *n != NodeEntitiesInfo::new(n_name.clone());
                    }
                }
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(20)),
            Err(e) => panic!("reading ros_discovery_info: {e:?}"),
        }
    }
    let waited = joined.elapsed();
    node.shutdown();
    assert!(heard_late >= 2, "announcements of the node heard 2 s to {waited:?} after a reader joined: {heard_late}; want >= 2");
    assert!(listed_with_entities, "the announcements list the node's writers");
}
