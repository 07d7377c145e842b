//! The simulator's app flash, laid out by the partition table (`base_core::update::
//! partitions`): two app slots and otadata, booted through the core's model of the
//! bootloader (`base_core::update::boot`). The images are synthetic: valid ESP app
//! images for the simulated chip with an app descriptor, whose version string chooses
//! what the virtual firmware does at boot, so that a whole update, a rollback and a
//! failed trial all run on the host.

use base_core::can::RawFrame;
use base_core::can::update::UpdateCommand;
use base_core::update::boot::{self, Bootloader};
use base_core::update::image::{self, Chip, ImageInfo};
use base_core::update::otadata::Slot;
use base_core::update::partitions::{self, SLOT_LEN};
use base_runtime::hw::{CanError, CanRx, NorFlash};
use base_runtime::update::{PROJECT, UpdateFlash};
use sha2::{Digest, Sha256};

/// The chip the simulator claims to be.
pub const SIM_CHIP: Chip = Chip::Esp32c3;

/// A version ending in this panics at boot, after arming its trial.
pub const PANIC_SUFFIX: &str = "-sim-panic";
/// A version ending in this never takes a CONFIRM: its trial runs out.
pub const NO_CONFIRM_SUFFIX: &str = "-sim-noconfirm";
/// A version ending in this was built with drive settings the firmware refuses: the
/// drives' own timeout off, their factory value (docs/drives.md, "Settings the
/// firmware refuses").
pub const REFUSED_DRIVES_SUFFIX: &str = "-sim-timeout-off";

/// The version of the image a blank simulator flash starts with.
pub const FACTORY_VERSION: &str = env!("CARGO_PKG_VERSION");

/// Bytes of filler in a synthetic image: about a C3 firmware's size.
pub const TYPICAL_PAYLOAD: usize = 600 * 1024;

/// What the virtual firmware does when it starts, by its version.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Behaviour {
    Healthy,
    PanicsAtBoot,
    NeverConfirms,
    /// Runs with [`Behaviour::settings`] the firmware refuses.
    RefusedDriveSettings,
}

impl Behaviour {
    pub fn of(version: &str) -> Self {
        if version.ends_with(PANIC_SUFFIX) {
            Self::PanicsAtBoot
        } else if version.ends_with(NO_CONFIRM_SUFFIX) {
            Self::NeverConfirms
        } else if version.ends_with(REFUSED_DRIVES_SUFFIX) {
            Self::RefusedDriveSettings
        } else {
            Self::Healthy
        }
    }

    /// The board settings this firmware was built with.
    pub fn settings(self) -> base_runtime::Settings {
        let mut settings = base_runtime::Settings::DEFAULT;
        if self == Self::RefusedDriveSettings {
            settings.drives.drive_comm_timeout_ms = 0;
        }
        settings
    }
}

/// A valid app image for `chip`: header, one segment that starts with an app
/// descriptor naming `project` and `version`, then `payload_len` bytes of filler, the
/// XOR checksum and the appended SHA-256, as `espflash save-image` lays them out.
pub fn synthetic_image(chip: Chip, project: &str, version: &str, payload_len: usize) -> Vec<u8> {
    secured_image(chip, project, version, 0, payload_len)
}

/// [`synthetic_image`] with the app descriptor's `secure_version` (the security
/// version signed updates must not go below).
pub fn secured_image(
    chip: Chip,
    project: &str,
    version: &str,
    security_version: u32,
    payload_len: usize,
) -> Vec<u8> {
    const DESC_LEN: usize = 256;
    let mut data = vec![0u8; DESC_LEN];
    data[0..4].copy_from_slice(&image::APP_DESC_MAGIC.to_le_bytes());
    data[4..8].copy_from_slice(&security_version.to_le_bytes());
    let text = |data: &mut [u8], at: usize, text: &str| {
        let len = text.len().min(31);
        data[at..at + len].copy_from_slice(&text.as_bytes()[..len]);
    };
    text(&mut data, 16, version);
    text(&mut data, 48, project);
    // Filler that differs between versions, so two images never share a digest.
    let seed = Sha256::digest(version.as_bytes());
    data.extend((0..payload_len).map(|i| seed[i % 32] ^ (i as u8)));

    let mut out = vec![0u8; 24];
    out[0] = image::IMAGE_MAGIC;
    out[1] = 1;
    out[12..14].copy_from_slice(&chip.id().to_le_bytes());
    out[23] = 1;
    out.extend_from_slice(&0x3C00_0020u32.to_le_bytes());
    out.extend_from_slice(&(data.len() as u32).to_le_bytes());
    let checksum = data.iter().fold(0xEF, |sum, byte| sum ^ byte);
    out.extend_from_slice(&data);
    while out.len() % 16 != 15 {
        out.push(0);
    }
    out.push(checksum);
    let digest = Sha256::digest(&out);
    out.extend_from_slice(&digest);
    out
}

/// The simulator's own image, for its chip and project.
pub fn sim_image(version: &str, payload_len: usize) -> Vec<u8> {
    synthetic_image(SIM_CHIP, PROJECT, version, payload_len)
}

/// The slot and version the bootloader started.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Booted {
    pub slot: Slot,
    pub version: String,
    /// The app descriptor's `secure_version`: the floor for the next update.
    pub security_version: u32,
}

async fn read_slot<F: NorFlash>(flash: &mut F, slot: Slot) -> Vec<u8> {
    let mut bytes = vec![0xFF; SLOT_LEN as usize];
    let offset = partitions::slot(slot).offset;
    if flash.read(offset, &mut bytes).await.is_err() {
        bytes.fill(0xFF);
    }
    bytes
}

/// The slot's image as the bootloader checks it: `Some` when it would load.
pub async fn slot_image<F: NorFlash>(flash: &mut F, slot: Slot) -> Option<ImageInfo> {
    let bytes = read_slot(flash, slot).await;
    let info = ImageInfo::parse(&bytes, SIM_CHIP, PROJECT).ok()?;
    image::verify_whole(&bytes, SLOT_LEN as usize).ok()?;
    Some(info)
}

/// A blank flash gets the factory image in `ota_0` and an erased otadata, as a USB
/// flash with `--erase-parts otadata` leaves the board. Returns whether it did.
pub async fn install_factory_image<F: NorFlash>(flash: &mut F) -> bool {
    let mut first = [0u8; 4];
    for slot in [Slot::Ota0, Slot::Ota1] {
        let _ = flash.read(partitions::slot(slot).offset, &mut first).await;
        if first != [0xFF; 4] {
            return false;
        }
    }
    let image = sim_image(FACTORY_VERSION, TYPICAL_PAYLOAD);
    let at = partitions::OTA_0.offset;
    let padded_len = image.len().next_multiple_of(F::ERASE_SIZE);
    let mut padded = image;
    padded.resize(padded_len, 0xFF);
    let erased = flash.erase(at, at + padded_len as u32).await.is_ok()
        && flash
            .erase(partitions::OTADATA.offset, partitions::OTADATA.end())
            .await
            .is_ok();
    erased && flash.write(at, &padded).await.is_ok()
}

/// Boots as the bootloader without app rollback does: its otadata writes are made,
/// and the started slot and its version returned; `None` when no image loads.
pub async fn boot<F: NorFlash + Clone>(flash: &mut F) -> Option<Booted> {
    let mut otadata_flash = UpdateFlash::new(flash.clone(), Slot::Ota0);
    let otadata = otadata_flash.read_otadata().await.ok()?;
    let mut images = [None, None];
    for slot in [Slot::Ota0, Slot::Ota1] {
        images[slot.index()] = slot_image(flash, slot).await;
    }
    let image_ok = [images[0].is_some(), images[1].is_some()];
    let outcome = boot::boot(&otadata, image_ok, Bootloader::Plain);
    for write in &outcome.writes {
        // A failed write here only changes what the next boot sees, as on the chip.
        let _ = otadata_flash.write_otadata(*write).await;
    }
    let slot = outcome.started?;
    let info = images[slot.index()]?;
    Some(Booted {
        slot,
        version: info.version.as_str().to_owned(),
        security_version: info.security_version,
    })
}

/// The receive half of a firmware that never hears CONFIRM (when `deaf`): the
/// virtual firmware of a `-sim-noconfirm` image, whose trial must run out.
pub struct DeafToConfirm<R> {
    pub rx: R,
    pub deaf: bool,
}

impl<R: CanRx> CanRx for DeafToConfirm<R> {
    type Frame = R::Frame;

    async fn receive(&mut self) -> Result<R::Frame, CanError> {
        let confirm = UpdateCommand::Confirm { session: 0 }.encode();
        loop {
            let frame = self.rx.receive().await?;
            let is_confirm = RawFrame::from_frame(&frame).is_some_and(|raw| {
                raw.id() == confirm.id() && raw.data().first() == confirm.data().first()
            });
            if !(self.deaf && is_confirm) {
                return Ok(frame);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flash::RamFlash;
    use crate::runtime::block_on;

    #[test]
    fn a_blank_flash_boots_the_factory_image_from_ota_0() {
        let mut flash = RamFlash::new(partitions::FLASH_SIZE as usize);
        block_on(async {
            assert_eq!(boot(&mut flash).await, None);
            assert!(install_factory_image(&mut flash).await);
            assert!(!install_factory_image(&mut flash).await);
            let booted = boot(&mut flash).await.expect("the factory image boots");
            assert_eq!(booted.slot, Slot::Ota0);
            assert_eq!(booted.version, FACTORY_VERSION);
        });
    }

    #[test]
    fn synthetic_images_pass_the_bootloader_checks_and_name_their_behaviour() {
        let image = sim_image("0.9.0-sim-panic", 5000);
        assert!(image::verify_whole(&image, SLOT_LEN as usize).is_ok());
        let info = ImageInfo::parse(&image, SIM_CHIP, PROJECT).unwrap();
        assert_eq!(
            Behaviour::of(info.version.as_str()),
            Behaviour::PanicsAtBoot
        );
        assert_eq!(
            Behaviour::of("0.9.0-sim-noconfirm"),
            Behaviour::NeverConfirms
        );
        assert_eq!(
            Behaviour::of("0.9.0-sim-timeout-off"),
            Behaviour::RefusedDriveSettings
        );
        assert!(
            Behaviour::RefusedDriveSettings
                .settings()
                .drives
                .check()
                .is_err()
        );
        assert_eq!(Behaviour::of("0.9.0"), Behaviour::Healthy);
        assert!(Behaviour::Healthy.settings().drives.check().is_ok());
    }
}
