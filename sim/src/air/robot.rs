//! The whole virtual robot with the air: the firmware, both remote tasks through the
//! HCI splitter on the air's dual-mode controller, and the pads, on the virtual clock.

use base_runtime::ble as remote;
use base_runtime::channels::Channels;
use base_runtime::classic;
use embassy_futures::join::join;
use embassy_futures::select::{Either3, select3};
use embassy_time::Timer;

use super::Air;
use crate::ble::{BOND_FLASH_SIZE, HCI_SLOTS, ROBOT_MAC};
use crate::flash::RamFlash;
use crate::robot::{Pc, VirtualRobot};
use crate::runtime::block_on;

/// A robot and the air around it. The robot's hardware, its bond partition and the
/// air (with its pads and their bonds) outlive a run, so a second run is a reboot of
/// the controller alone.
pub struct AirRobot {
    pub robot: VirtualRobot,
    pub bond_flash: RamFlash,
    pub air: Air,
}

impl AirRobot {
    /// A robot on a blank flash, in an empty air seeded with `seed`.
    pub fn new(seed: u64) -> Self {
        Self::around(VirtualRobot::new(), seed)
    }

    /// This robot (its drives, settings and faults as the caller made them) on a blank
    /// bond flash, in an empty air seeded with `seed`.
    pub fn around(robot: VirtualRobot, seed: u64) -> Self {
        Self {
            robot,
            bond_flash: RamFlash::new(BOND_FLASH_SIZE),
            air: Air::new(seed),
        }
    }

    /// Boots the controller with both remotes on the air's controller, on the virtual
    /// clock, and runs `script` beside them and the air; the controller (and its radio)
    /// loses power when the script returns.
    pub fn run<T>(&self, script: impl AsyncFnOnce(&Pc) -> T) -> T {
        block_on(self.boot(script))
    }

    /// [`Self::run`] as a future, for an executor of the caller's.
    pub async fn boot<T>(&self, script: impl AsyncFnOnce(&Pc) -> T) -> T {
        let (hardware, pc) = self.robot.boot();
        let bluetooth = hardware.bluetooth;
        let channels = Channels::new();
        let transport = self.air.robot_transport();
        let firmware = async {
            Timer::after(self.robot.boot_time).await;
            join(
                base_runtime::run(hardware, self.robot.settings, &channels),
                async {
                    remote::wait_until_on(bluetooth, &channels.remote_requests, || {
                        self.robot.rtc_ram.turned_on()
                    })
                    .await;
                    classic::run_both::<_, _, HCI_SLOTS>(
                        &transport,
                        remote::random_static_address(&ROBOT_MAC),
                        self.bond_flash.clone(),
                        0..BOND_FLASH_SIZE as u32,
                        channels.remote_ends(),
                    )
                    .await
                },
            )
            .await
        };
        let result = match select3(firmware, self.air.run(), script(&pc)).await {
            Either3::First((never, _)) => never,
            Either3::Second(never) => never,
            Either3::Third(result) => result,
        };
        self.air.robot_off();
        result
    }
}
