//! Ports: how a node meets the world. A node's turn ([`crate::node::Node::turn`]) takes its
//! ports as trait objects, so the same node runs on DDS (the `oilfilm-nodes` crate), on a
//! bag's messages ([`crate::runner::bag`]) or in memory ([`memory`], [`crate::runner::memory`]),
//! and a replay gives the live results bit for bit.

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

    /// How many readers the topic has now, if the port knows (DDS: the subscriptions
    /// discovery has matched; in memory: the subscribers). `None`: it cannot tell.
    fn readers(&mut self) -> Option<usize> {
        None
    }

    /// Waits (at most `timeout`) until every reliable reader has what was published; false
    /// when one has not. A port that delivers at once (in memory) has nothing to wait for.
    fn flush(&mut self, _timeout: std::time::Duration) -> Result<bool, NodeError> {
        Ok(true)
    }
}

impl<M, P: Publish<M> + ?Sized> Publish<M> for &mut P {
    fn publish(&mut self, message: M) -> Result<(), NodeError> {
        (**self).publish(message)
    }
    fn readers(&mut self) -> Option<usize> {
        (**self).readers()
    }
    fn flush(&mut self, timeout: std::time::Duration) -> Result<bool, NodeError> {
        (**self).flush(timeout)
    }
}

impl<M, R: Receive<M> + ?Sized> Receive<M> for &mut R {
    fn receive(&mut self) -> Result<Option<M>, NodeError> {
        (**self).receive()
    }
}

/// Where a node takes messages of one topic from; `Ok(None)` when none is waiting.
pub trait Receive<M> {
    fn receive(&mut self) -> Result<Option<M>, NodeError>;
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

        fn readers(&mut self) -> Option<usize> {
            Some(self.bus.subscribers.lock().unwrap_or_else(PoisonError::into_inner).len())
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
