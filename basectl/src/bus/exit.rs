//! What must happen however basectl ends: a normal return, an error, Ctrl-C or
//! SIGTERM. An SLCAN adapter is told `C` and its tty given back as it was, the
//! terminal leaves raw mode. Each action runs once: when its [`Registration`] is
//! dropped, or from the signal thread [`on_signals`] starts.

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

type Action = Box<dyn FnOnce() + Send>;

static ACTIONS: Mutex<Vec<(u64, Action)>> = Mutex::new(Vec::new());
static NEXT_ID: AtomicU64 = AtomicU64::new(1);

/// An action waiting to run; it runs when this is dropped.
#[derive(Debug)]
pub struct Registration {
    id: u64,
}

/// Registers `action` to run at the end.
pub fn register(action: Action) -> Registration {
    let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
    lock().push((id, action));
    Registration { id }
}

fn lock() -> std::sync::MutexGuard<'static, Vec<(u64, Action)>> {
    ACTIONS
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Registration {
    /// Runs the action now, if it has not run yet.
    pub fn run(&mut self) {
        let action = {
            let mut actions = lock();
            let index = actions.iter().position(|(id, _)| *id == self.id);
            index.map(|index| actions.remove(index).1)
        };
        if let Some(action) = action {
            action();
        }
    }
}

impl Drop for Registration {
    fn drop(&mut self) {
        self.run();
    }
}

/// Runs every action still registered, newest first.
pub fn run_all() {
    let actions = std::mem::take(&mut *lock());
    for (_, action) in actions.into_iter().rev() {
        action();
    }
}

/// On SIGINT (Ctrl-C), SIGTERM or SIGHUP: runs every registered action and exits
/// with 130, the shell's code for a program ended by Ctrl-C.
pub fn on_signals() -> std::io::Result<()> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP])?;
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            if signals.forever().next().is_some() {
                run_all();
                std::process::exit(130);
            }
        })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::sync::atomic::AtomicU32;

    #[test]
    fn an_action_runs_once_whether_run_early_or_dropped() {
        let runs = Arc::new(AtomicU32::new(0));
        let counted = runs.clone();
        let mut registration = register(Box::new(move || {
            counted.fetch_add(1, Ordering::SeqCst);
        }));
        registration.run();
        registration.run();
        drop(registration);
        assert_eq!(runs.load(Ordering::SeqCst), 1);
    }
}
