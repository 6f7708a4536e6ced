//! The runtime's messages, on the application's standard error: a runtime
//! loaded into someone else's process cannot rely on its logging set-up.
//! `NEDRT_OPENXR_LOG=debug` adds the debug lines, `=quiet` keeps only
//! errors.

use std::sync::LazyLock;

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    Error,
    Warn,
    Info,
    Debug,
}

static MAX: LazyLock<Level> =
    LazyLock::new(|| match std::env::var("NEDRT_OPENXR_LOG").as_deref() {
        Ok("debug") => Level::Debug,
        Ok("quiet") => Level::Error,
        _ => Level::Info,
    });

pub fn emit(level: Level, message: &str) {
    if level <= *MAX {
        let tag = match level {
            Level::Error => "error: ",
            Level::Warn => "warning: ",
            Level::Info | Level::Debug => "",
        };
        eprintln!("nedrt-openxr: {tag}{message}");
    }
}

macro_rules! log_error { ($($t:tt)*) => { $crate::log::emit($crate::log::Level::Error, &format!($($t)*)) } }
macro_rules! log_warn { ($($t:tt)*) => { $crate::log::emit($crate::log::Level::Warn, &format!($($t)*)) } }
macro_rules! log_info { ($($t:tt)*) => { $crate::log::emit($crate::log::Level::Info, &format!($($t)*)) } }
macro_rules! log_debug { ($($t:tt)*) => { $crate::log::emit($crate::log::Level::Debug, &format!($($t)*)) } }
