//! Acceptance filters for the CAN controller, so that its receive FIFO holds the robot
//! PC's commands and little else. Bus controllers of the SJA1000 family (the ESP32's
//! TWAI among them) offer two standard-ID filters, each a code and a mask; this module
//! computes them from the protocol's IDs, so a new command ID cannot be forgotten here.
//! The filters are a load shedder, not a gate: [`super::Command::decode`] still checks
//! every ID.

use super::{MAX_STANDARD_ID, id};

/// One code/mask filter over the 11-bit identifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AcceptanceFilter {
    /// The identifier bits to match.
    pub code: u16,
    /// Which bits must match: a set bit compares, a clear bit is "don't care".
    pub mask: u16,
}

impl AcceptanceFilter {
    /// The narrowest single filter that accepts every ID of `ids`: the bits on which
    /// they all agree are compared, the others are free.
    pub const fn covering(ids: &[u16]) -> Self {
        assert!(!ids.is_empty());
        let mut all_ones = MAX_STANDARD_ID;
        let mut all_zeros = MAX_STANDARD_ID;
        let mut index = 0;
        while index < ids.len() {
            all_ones &= ids[index];
            all_zeros &= !ids[index];
            index += 1;
        }
        AcceptanceFilter {
            code: all_ones,
            mask: all_ones | all_zeros,
        }
    }

    pub const fn accepts(&self, id: u16) -> bool {
        id & self.mask == self.code
    }
}

/// The two filters for the commands. The grouping keeps the accepted set small: the
/// register, odometry, heartbeat and calibration IDs sit together in 0x003–0x008, the
/// velocity and enable IDs are the two outliers.
pub const COMMAND_FILTERS: [AcceptanceFilter; 2] = [
    AcceptanceFilter::covering(&[
        id::REGISTER_WRITE,
        id::REGISTER_READ,
        id::RESET_ODOMETRY,
        id::HEARTBEAT,
        id::SCALE_CALIBRATION,
        id::ODOMETRY_CALIBRATION,
    ]),
    AcceptanceFilter::covering(&[id::VELOCITY, id::ENABLE]),
];

#[cfg(test)]
mod tests {
    use super::*;

    fn accepted(id: u16) -> bool {
        COMMAND_FILTERS.iter().any(|filter| filter.accepts(id))
    }

    #[test]
    fn every_command_passes_the_filters() {
        for id in id::COMMANDS {
            assert!(accepted(id), "{id:#05x}");
        }
    }

    #[test]
    fn the_update_ids_pass_the_filters_without_widening_them() {
        for id in id::UPDATE {
            assert!(accepted(id), "{id:#05x}");
        }
        // The reply ID is the base controller's own, not for its receive FIFO.
        assert!(!accepted(id::UPDATE_REPLY));
    }

    #[test]
    fn the_filters_pass_32_of_the_2048_ids() {
        let count = (0..=MAX_STANDARD_ID).filter(|&id| accepted(id)).count();
        assert_eq!(count, 32);
    }

    #[test]
    fn a_filter_over_one_id_passes_only_that_id() {
        let filter = AcceptanceFilter::covering(&[id::ENABLE]);
        assert_eq!(filter.mask, MAX_STANDARD_ID);
        let passed: Vec<u16> = (0..=MAX_STANDARD_ID)
            .filter(|&id| filter.accepts(id))
            .collect();
        assert_eq!(passed, [id::ENABLE]);
    }

    #[test]
    fn the_covering_filter_frees_exactly_the_bits_that_differ() {
        let filter = AcceptanceFilter::covering(&[0x0C8, 0x2E4]);
        assert_eq!(filter.code, 0x0C0);
        assert_eq!(filter.mask, 0x7FF & !(0x0C8 ^ 0x2E4));
    }
}
