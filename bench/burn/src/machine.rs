//! The facts of the machine a report was measured on: the adapter, nedrt's
//! commit and the load average.

use std::path::Path;

use serde_json::{Value, json};

pub(super) fn adapter_json(info: &wgpu::AdapterInfo) -> Value {
    json!({
        "name": info.name,
        "backend": format!("{:?}", info.backend),
        "device_type": format!("{:?}", info.device_type),
        "driver": info.driver,
        "driver_info": info.driver_info,
        "vendor": info.vendor,
        "device": info.device,
    })
}

pub(super) fn describe(info: &wgpu::AdapterInfo) -> String {
    format!(
        "{} ({:?}, {:?}, driver {} {})",
        info.name, info.backend, info.device_type, info.driver, info.driver_info
    )
}

/// nedrt's commit, and whether its runtime differs from it (read-only git).
pub(super) fn nedrt_commit() -> String {
    if let Ok(c) = std::env::var("NEDRT_COMMIT") {
        return c;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .args(args)
            .current_dir(&root)
            .env("GIT_OPTIONAL_LOCKS", "0")
            .output()
            .ok()
    };
    let Some(out) = git(&["rev-parse", "--short", "HEAD"]).filter(|o| o.status.success()) else {
        return "unknown".into();
    };
    let mut commit = String::from_utf8_lossy(&out.stdout).trim().to_string();
    if git(&["diff", "--quiet", "HEAD", "--", "runtime"]).is_some_and(|o| !o.status.success()) {
        commit.push_str(" (+ uncommitted changes in runtime/)");
    }
    commit
}

/// The machine's load average (Linux), for the report: other work on the
/// cores slows a CPU adapter such as lavapipe.
pub(super) fn loadavg() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "n/a".into())
}
