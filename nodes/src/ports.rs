//! Ports: how a node core meets the world. A node's `poll` takes its ports as trait objects,
//! so the same core runs on DDS ([`crate::dds`]), on a bag, or in memory ([`memory`]) in
//! tests, and a replay gives the live results bit for bit.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, PoisonError};

use crate::error::NodeError;

/// A message as serialised CDR bytes, the 4-byte encapsulation header (`00 01 00 00`)
/// included: what a rosbag2 bag stores. The recorder takes these and the player sends them,
/// so a message crosses a record and a replay byte for byte, whatever its type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawCdr(pub Vec<u8>);

/// Where a node sends messages of one topic.
pub trait Publish<M> {
    fn publish(&mut self, message: M) -> Result<(), NodeError>;
}

/// Where a node takes messages of one topic from; `Ok(None)` when none is waiting.
pub trait Receive<M> {
    fn receive(&mut self) -> Result<Option<M>, NodeError>;
}

/// A port that never delivers anything (a topic the node does not use in this setup).
pub struct Nothing;

impl<M> Receive<M> for Nothing {
    fn receive(&mut self) -> Result<Option<M>, NodeError> {
        Ok(None)
    }
}

/// A port that drops what it is given.
pub struct Discard;

impl<M> Publish<M> for Discard {
    fn publish(&mut self, _message: M) -> Result<(), NodeError> {
        Ok(())
    }
}

/// In-memory topics: every subscriber gets every message published after it subscribed,
/// in order, like a reliable keep-all topic.
pub mod memory {
    use super::*;

    type Queues<M> = Arc<Mutex<Vec<Arc<Mutex<VecDeque<M>>>>>>;

    /// One topic.
    pub struct Bus<M> {
        subscribers: Queues<M>,
    }

    impl<M> Clone for Bus<M> {
        fn clone(&self) -> Self {
            Self { subscribers: Arc::clone(&self.subscribers) }
        }
    }

    impl<M: Clone> Default for Bus<M> {
        fn default() -> Self {
            Self { subscribers: Arc::new(Mutex::new(Vec::new())) }
        }
    }

    impl<M: Clone> Bus<M> {
        pub fn new() -> Self {
            Self::default()
        }

        pub fn publisher(&self) -> Publisher<M> {
            Publisher { bus: self.clone() }
        }

        pub fn subscriber(&self) -> Subscriber<M> {
            let queue = Arc::new(Mutex::new(VecDeque::new()));
            self.subscribers.lock().unwrap_or_else(PoisonError::into_inner).push(Arc::clone(&queue));
            Subscriber { queue }
        }
    }

    pub struct Publisher<M> {
        bus: Bus<M>,
    }

    impl<M: Clone> Publish<M> for Publisher<M> {
        fn publish(&mut self, message: M) -> Result<(), NodeError> {
            let subs = self.bus.subscribers.lock().unwrap_or_else(PoisonError::into_inner);
            for q in subs.iter() {
                q.lock().unwrap_or_else(PoisonError::into_inner).push_back(message.clone());
            }
            Ok(())
        }
    }

    pub struct Subscriber<M> {
        queue: Arc<Mutex<VecDeque<M>>>,
    }

    impl<M> Receive<M> for Subscriber<M> {
        fn receive(&mut self) -> Result<Option<M>, NodeError> {
            Ok(self.queue.lock().unwrap_or_else(PoisonError::into_inner).pop_front())
        }
    }

    impl<M> Subscriber<M> {
        /// Everything waiting, in order.
        pub fn drain(&mut self) -> Vec<M> {
            self.queue.lock().unwrap_or_else(PoisonError::into_inner).drain(..).collect()
        }
    }
}

/// A port replaying a list of messages (a bag's topic, a golden file).
pub struct Replay<M> {
    messages: VecDeque<M>,
}

impl<M> Replay<M> {
    pub fn new(messages: impl IntoIterator<Item = M>) -> Self {
        Self { messages: messages.into_iter().collect() }
    }

    pub fn is_empty(&self) -> bool {
        self.messages.is_empty()
    }
}

impl<M> Receive<M> for Replay<M> {
    fn receive(&mut self) -> Result<Option<M>, NodeError> {
        Ok(self.messages.pop_front())
    }
}

/// Collects what a node publishes.
pub struct Collect<M>(pub Vec<M>);

impl<M> Default for Collect<M> {
    fn default() -> Self {
        Self(Vec::new())
    }
}

impl<M> Publish<M> for Collect<M> {
    fn publish(&mut self, message: M) -> Result<(), NodeError> {
        self.0.push(message);
        Ok(())
    }
}
