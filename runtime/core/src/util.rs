//! Small helpers shared by the readers and writers: size-capped input,
//! atomic file output, bounded messages.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// Temporary files being written now, so that a stop signal can remove
/// them before the process exits ([`remove_pending_temp_files`]).
static PENDING: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

fn pending() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    PENDING.lock().unwrap_or_else(|p| p.into_inner())
}

/// Removes every temporary file an unfinished [`write_atomic`] or
/// [`write_atomic_with`] holds and exits with `code`, still holding the
/// list, so no write can start or finish in between: for a signal
/// handler, so that a stopped command leaves neither a half-written output
/// nor its temporary.
pub fn exit_removing_temp_files(code: i32) -> ! {
    let mut list = pending();
    for tmp in list.drain(..) {
        let _ = std::fs::remove_file(tmp);
    }
    std::process::exit(code)
}

/// Writes `path` through `write`, which is given a temporary path in the
/// same folder (a hidden name ending in the same extension, so writers that
/// pick their format by extension still work); the temporary is renamed
/// into place only when `write` succeeded, and removed otherwise. Readers
/// never see a half-written file and a failure leaves any previous file
/// intact.
pub fn write_atomic_with<E: From<std::io::Error>>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), E> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let file_name = path
        .file_name()
        .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "no file name"))?;
    let tmp = dir.join(format!(
        ".tmp{}.{}",
        std::process::id(),
        file_name.to_string_lossy()
    ));
    {
        // Created under the list's lock: a stop either sees it or comes first.
        let mut list = pending();
        std::fs::File::create(&tmp)?;
        list.push(tmp.clone());
    }
    let result = write(&tmp).and_then(|()| Ok(std::fs::rename(&tmp, path)?));
    let mut list = pending();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    list.retain(|p| p != &tmp);
    result
}

/// Writes `bytes` to `path` atomically ([`write_atomic_with`]), synced to
/// the disk before the rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomic_with(path, |tmp| {
        let mut f = std::fs::File::create(tmp)?;
        f.write_all(bytes)?;
        f.sync_all()
    })
}

/// Reads at most `max_bytes` of `path`; a longer file (or an endless one,
/// such as `/dev/zero`) is an `InvalidData` error naming the cap, so a
/// wrong path cannot exhaust memory.
pub fn read_capped(path: &Path, max_bytes: u64) -> std::io::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    std::fs::File::open(path)?
        .take(max_bytes + 1)
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "larger than {} MiB, the most this file can be",
                max_bytes >> 20
            ),
        ));
    }
    Ok(bytes)
}

/// A fresh, empty hidden sibling of folder `dir` (`.NAME.partial-PID`,
/// its parent made if missing) to write a whole folder into before it
/// takes `dir`'s place, so that a failure leaves nothing half-written.
pub fn staging_sibling(dir: &Path) -> std::io::Result<std::path::PathBuf> {
    let parent = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => std::path::PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent)?;
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "folder".into());
    let staging = parent.join(format!(".{name}.partial-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&staging);
    std::fs::create_dir(&staging)?;
    Ok(staging)
}

/// `text` cut to at most `max_chars` characters, with the number left out,
/// so that a message quoting user input stays a line.
pub fn bounded(text: &str, max_chars: usize) -> String {
    let n = text.chars().count();
    if n <= max_chars {
        return text.to_string();
    }
    let kept: String = text.chars().take(max_chars).collect();
    format!("{kept}… ({} more characters)", n - max_chars)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_atomic_write_leaves_the_old_file_and_no_temporary() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("out.png");
        write_atomic(&p, b"old").expect("first write");
        let e = write_atomic_with(&p, |tmp| {
            std::fs::write(tmp, b"half")?;
            Err(std::io::Error::other("disk full"))
        });
        assert!(e.is_err());
        assert_eq!(std::fs::read(&p).expect("kept"), b"old");
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .expect("list")
            .map(|e| e.expect("entry").file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("out.png")]);
        assert!(!pending().iter().any(|t| t.starts_with(dir.path())));
    }

    #[test]
    fn an_unfinished_write_lists_its_temporary_until_it_ends() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("chart.svg");
        write_atomic_with(&p, |tmp| -> std::io::Result<()> {
            assert!(tmp.extension().is_some_and(|e| e == "svg"), "{tmp:?}");
            assert!(tmp.exists(), "created before the writer runs");
            assert!(pending().contains(&tmp.to_path_buf()));
            std::fs::write(tmp, b"<svg/>")
        })
        .expect("write");
        assert_eq!(std::fs::read(&p).expect("written"), b"<svg/>");
        assert!(!pending().iter().any(|t| t.starts_with(dir.path())));
    }

    #[test]
    fn bounded_keeps_short_text_and_counts_what_it_cuts() {
        assert_eq!(bounded("abc", 3), "abc");
        assert_eq!(bounded("äbcdé", 2), "äb… (3 more characters)");
    }

    #[test]
    fn read_capped_reads_up_to_the_cap_and_refuses_past_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("f");
        std::fs::write(&p, [7u8; 10]).expect("write");
        assert_eq!(read_capped(&p, 10).expect("at the cap"), vec![7u8; 10]);
        let e = read_capped(&p, 9).expect_err("past the cap");
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidData);
        let e = read_capped(Path::new("/dev/zero"), 1 << 20).expect_err("endless");
        assert!(e.to_string().contains("larger than 1 MiB"), "{e}");
    }
}
