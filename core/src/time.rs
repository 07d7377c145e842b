//! Time as a plain value. The core never reads a clock: every function that cares
//! about time takes `now: Timestamp`, so the async shell (or a test) decides what "now" is.

/// A point in time, in milliseconds since boot. Milliseconds are the unit of every
/// period and timeout of the CAN protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Timestamp {
    ms: u64,
}

impl Timestamp {
    pub const BOOT: Timestamp = Timestamp { ms: 0 };

    pub const fn from_millis(ms: u64) -> Self {
        Self { ms }
    }

    pub const fn as_millis(self) -> u64 {
        self.ms
    }

    /// Milliseconds from `earlier` to `self`; zero if `earlier` is in the future.
    pub const fn millis_since(self, earlier: Timestamp) -> u64 {
        self.ms.saturating_sub(earlier.ms)
    }

    pub const fn plus_millis(self, ms: u64) -> Timestamp {
        Timestamp {
            ms: self.ms.saturating_add(ms),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn millis_since_saturates_instead_of_wrapping() {
        let early = Timestamp::from_millis(10);
        let late = Timestamp::from_millis(25);
        assert_eq!(late.millis_since(early), 15);
        assert_eq!(early.millis_since(late), 0);
    }
}
