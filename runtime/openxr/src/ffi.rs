//! What every entry point shares: the catch of panics at the C boundary,
//! the two-call idiom, fixed-size C strings and structure checks.

use std::ffi::{CStr, c_char};
use std::sync::{Mutex, MutexGuard};

use openxr_sys as xr;

/// An entry point's outcome before it crosses the C boundary.
pub type XrResult<T = ()> = Result<T, xr::Result>;

/// Locks a mutex, recovering it if a panicking entry point poisoned it:
/// every entry point leaves its object consistent between statements, and
/// one failed call must not fail every later one.
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Runs an entry point's body, turning a panic into
/// `XR_ERROR_RUNTIME_FAILURE`: unwinding into the application's C frames
/// is undefined behaviour, and a runtime bug must not take the application
/// down with it.
pub fn guard(name: &str, body: impl FnOnce() -> XrResult<xr::Result>) -> xr::Result {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(body)) {
        Ok(Ok(r)) => r,
        Ok(Err(e)) => {
            log_debug!("{name}: {e:?}");
            e
        }
        Err(_) => {
            log_error!("{name}: the runtime panicked; answered XR_ERROR_RUNTIME_FAILURE");
            xr::Result::ERROR_RUNTIME_FAILURE
        }
    }
}

/// A required pointer argument, or `XR_ERROR_VALIDATION_FAILURE`.
pub fn non_null<T>(p: *const T) -> XrResult<*const T> {
    if p.is_null() {
        Err(xr::Result::ERROR_VALIDATION_FAILURE)
    } else {
        Ok(p)
    }
}

/// A required output pointer, or `XR_ERROR_VALIDATION_FAILURE`.
pub fn non_null_mut<T>(p: *mut T) -> XrResult<*mut T> {
    if p.is_null() {
        Err(xr::Result::ERROR_VALIDATION_FAILURE)
    } else {
        Ok(p)
    }
}

/// A structure whose `type` member the application must set.
pub fn expect_type(found: xr::StructureType, wanted: xr::StructureType) -> XrResult {
    if found == wanted {
        Ok(())
    } else {
        log_debug!("structure type {found:?} where {wanted:?} was expected");
        Err(xr::Result::ERROR_VALIDATION_FAILURE)
    }
}

/// The two-call idiom (OpenXR §2.11): with capacity 0, the count is
/// written and nothing else; otherwise the items are written if they fit,
/// else `XR_ERROR_SIZE_INSUFFICIENT`.
///
/// # Safety
/// `out` must be valid for `capacity` writes when `capacity > 0`, and
/// `count` valid for one write (both as the application passed them).
pub unsafe fn two_call<T: Copy>(
    capacity: u32,
    count: *mut u32,
    out: *mut T,
    items: &[T],
) -> XrResult<xr::Result> {
    let count = non_null_mut(count)?;
    let n = u32::try_from(items.len()).map_err(|_| xr::Result::ERROR_RUNTIME_FAILURE)?;
    // SAFETY: the caller guarantees `count` points at a u32 the
    // application owns; it was checked non-null above.
    unsafe { count.write(n) };
    if capacity == 0 {
        return Ok(xr::Result::SUCCESS);
    }
    if capacity < n {
        return Err(xr::Result::ERROR_SIZE_INSUFFICIENT);
    }
    let out = non_null_mut(out)?;
    for (i, item) in items.iter().enumerate() {
        // SAFETY: i < n ≤ capacity, and the caller guarantees `out` holds
        // `capacity` elements.
        unsafe { out.add(i).write(*item) };
    }
    Ok(xr::Result::SUCCESS)
}

/// As [`two_call`], for structures the application initialised: each
/// element's `type` is checked and only its payload is written.
///
/// # Safety
/// As [`two_call`].
pub unsafe fn two_call_with<T>(
    capacity: u32,
    count: *mut u32,
    out: *mut T,
    n: usize,
    mut fill: impl FnMut(&mut T, usize) -> XrResult,
) -> XrResult<xr::Result> {
    let count = non_null_mut(count)?;
    let n32 = u32::try_from(n).map_err(|_| xr::Result::ERROR_RUNTIME_FAILURE)?;
    // SAFETY: as in `two_call`.
    unsafe { count.write(n32) };
    if capacity == 0 {
        return Ok(xr::Result::SUCCESS);
    }
    if capacity < n32 {
        return Err(xr::Result::ERROR_SIZE_INSUFFICIENT);
    }
    let out = non_null_mut(out)?;
    for i in 0..n {
        // SAFETY: i < n ≤ capacity elements the caller guarantees.
        fill(unsafe { &mut *out.add(i) }, i)?;
    }
    Ok(xr::Result::SUCCESS)
}

/// The two-call idiom for a string: capacity and count include the
/// terminating NUL.
///
/// # Safety
/// `buffer` must be valid for `capacity` bytes when `capacity > 0`.
pub unsafe fn two_call_str(
    capacity: u32,
    count: *mut u32,
    buffer: *mut c_char,
    s: &str,
) -> XrResult<xr::Result> {
    let mut bytes: Vec<c_char> = s.bytes().map(|b| b as c_char).collect();
    bytes.push(0);
    // SAFETY: forwarded from the caller.
    unsafe { two_call(capacity, count, buffer, &bytes) }
}

/// Writes `s` into a fixed-size C string, truncated to fit with its NUL.
pub fn write_fixed(dst: &mut [c_char], s: &str) {
    let n = s.len().min(dst.len().saturating_sub(1));
    for (d, b) in dst.iter_mut().zip(s.bytes().take(n)) {
        *d = b as c_char;
    }
    if let Some(end) = dst.get_mut(n) {
        *end = 0;
    }
}

/// Reads a fixed-size C string; `None` if it has no NUL within its size
/// (the specification's validation failure) or is not UTF-8.
pub fn read_fixed(src: &[c_char]) -> Option<String> {
    let end = src.iter().position(|&c| c == 0)?;
    let bytes: Vec<u8> = src[..end].iter().map(|&c| c as u8).collect();
    String::from_utf8(bytes).ok()
}

/// Reads a NUL-terminated C string the application passed.
///
/// # Safety
/// `p` must be null or point at a NUL-terminated string.
pub unsafe fn read_cstr<'a>(p: *const c_char) -> XrResult<&'a str> {
    let p = non_null(p)?;
    // SAFETY: the caller guarantees a NUL-terminated string.
    unsafe { CStr::from_ptr(p) }
        .to_str()
        .map_err(|_| xr::Result::ERROR_VALIDATION_FAILURE)
}

/// CLOCK_MONOTONIC in nanoseconds: the protocol's clock, and so the
/// `XrTime` of this runtime.
pub fn now_ns() -> i64 {
    i64::try_from(nedrt_protocol::monotonic_ns()).unwrap_or(i64::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_two_call_idiom_counts_fills_and_refuses_short_buffers() {
        let items = [1u32, 2, 3];
        let mut count = 0;
        let mut out = [0u32; 3];
        // SAFETY: out holds 3 elements; count is a local.
        let r = unsafe { two_call(0, &mut count, out.as_mut_ptr(), &items) };
        assert_eq!((r, count), (Ok(xr::Result::SUCCESS), 3));
        // SAFETY: as above.
        let r = unsafe { two_call(2, &mut count, out.as_mut_ptr(), &items) };
        assert_eq!(r, Err(xr::Result::ERROR_SIZE_INSUFFICIENT));
        // SAFETY: as above.
        let r = unsafe { two_call(3, &mut count, out.as_mut_ptr(), &items) };
        assert_eq!((r, out), (Ok(xr::Result::SUCCESS), items));
        // SAFETY: a null count pointer is refused before any write.
        let r = unsafe { two_call(3, std::ptr::null_mut(), out.as_mut_ptr(), &items) };
        assert_eq!(r, Err(xr::Result::ERROR_VALIDATION_FAILURE));
    }

    #[test]
    fn fixed_strings_round_trip_truncated_and_refuse_a_missing_nul() {
        let mut buf = [1 as c_char; 8];
        write_fixed(&mut buf, "nedrt-openxr");
        assert_eq!(read_fixed(&buf).as_deref(), Some("nedrt-o"));
        assert_eq!(read_fixed(&[b'a' as c_char; 4]), None);
    }
}
