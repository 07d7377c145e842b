//! Firmware update over CAN with A/B slots and rollback: the pure parts. Which slot the
//! bootloader starts ([`otadata`], [`boot`]) and whether an image may be written at all
//! ([`image`]). The update task in the runtime writes the inactive slot and otadata
//! through these; the simulator boots through [`boot::boot`].
//!
//! The trial of a new image, with a bootloader that has no rollback of its own:
//! activation writes `{next seq, New}` into the inactive otadata sector (one write: a
//! power cut leaves the old entry active); the new image, first thing after start-up,
//! rewrites its entry as `Aborted` ("armed"), so any reset from then on boots the
//! previous slot; after its health checks it writes `Valid`.

/// The project name `esp_app_desc!` records for this firmware (the firmware crate's
/// name): an image naming another project is refused.
pub const PROJECT: &str = "base-controller-firmware";

pub mod boot;
pub mod image;
pub mod otadata;
pub mod partitions;
pub mod session;
pub mod signature;
pub mod trial;
