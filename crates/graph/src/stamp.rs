//! Time on the rig's clock as integer nanoseconds since the epoch.
//!
//! Every node computes sample times as `stamp of the frame + k / rate` in integer
//! nanoseconds, never by adding floating seconds near 1.7e9 s (an `f64` resolves only
//! ~0.2 us there, a few percent of the DAQ's 10 us multiplex step).

use oilfilm_msgs::Time;

/// Nanoseconds since the epoch of the rig clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Stamp(pub i64);

impl Stamp {
    pub fn from_time(t: &Time) -> Self {
        Self(i64::from(t.sec) * 1_000_000_000 + i64::from(t.nanosec))
    }

    /// The ROS time (saturating outside the int32 seconds range).
    pub fn to_time(self) -> Time {
        let sec = self.0.div_euclid(1_000_000_000);
        let nanosec = self.0.rem_euclid(1_000_000_000) as u32;
        match i32::try_from(sec) {
            Ok(sec) => Time { sec, nanosec },
            Err(_) if sec < 0 => Time { sec: i32::MIN, nanosec: 0 },
            Err(_) => Time { sec: i32::MAX, nanosec: 999_999_999 },
        }
    }

    /// The time `index` samples after this one at `rate_hz` (rounded to the nanosecond).
    pub fn after_samples(self, index: i64, rate_hz: f64) -> Self {
        Self(self.0.saturating_add((index as f64 * 1e9 / rate_hz).round() as i64))
    }

    /// Seconds from `origin` to this stamp.
    pub fn seconds_since(self, origin: Stamp) -> f64 {
        (self.0 - origin.0) as f64 * 1e-9
    }

    pub fn as_seconds(self) -> f64 {
        self.0 as f64 * 1e-9
    }

    /// The wall clock now.
    pub fn now() -> Self {
        let d = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        Self(i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_round_trip_and_negative_stamps() {
        for ns in [0_i64, 1, 999_999_999, 1_000_000_000, 1_700_000_000_123_456_789, -1, -1_000_000_001] {
            let t = Stamp(ns).to_time();
            assert!(t.nanosec < 1_000_000_000);
            assert_eq!(Stamp::from_time(&t), Stamp(ns), "{ns}");
        }
        assert_eq!(Stamp(0).after_samples(5000, 5000.0), Stamp(1_000_000_000));
        assert_eq!(Stamp(10).after_samples(1, 3.0), Stamp(10 + 333_333_333));
    }
}
