//! Logging macros that keep the library host-buildable: with the `defmt` feature (the
//! chip builds) they forward to defmt, whose level filter is `DEFMT_LOG` at build time;
//! without it they only borrow their arguments, so host builds log nothing and warn
//! about nothing. The format strings are defmt's (`{}`, `{=u8}`, …).
#![allow(unused_macros)]

#[cfg(feature = "defmt")]
macro_rules! log {
    ($level:ident, $($arg:tt)*) => { ::defmt::$level!($($arg)*) };
}

#[cfg(not(feature = "defmt"))]
macro_rules! log {
    ($level:ident, $format:literal $(, $arg:expr)* $(,)?) => {{
        let _ = ($(&$arg),*);
    }};
}

macro_rules! debug {
    ($($arg:tt)*) => { log!(debug, $($arg)*) };
}

macro_rules! info {
    ($($arg:tt)*) => { log!(info, $($arg)*) };
}

macro_rules! warn {
    ($($arg:tt)*) => { log!(warn, $($arg)*) };
}

macro_rules! error {
    ($($arg:tt)*) => { log!(error, $($arg)*) };
}
