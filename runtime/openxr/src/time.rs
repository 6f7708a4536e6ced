//! XR_KHR_convert_timespec_time: `XrTime` is CLOCK_MONOTONIC in
//! nanoseconds (the service's clock), so a `timespec` of that clock
//! converts exactly.

use openxr_sys as xr;

use crate::ffi::{guard, non_null, non_null_mut};
use crate::instance::CONVERT_TIMESPEC_TIME;
use crate::state::registry;

/// `struct timespec` on 64-bit Linux (`time_t` and `long` are 64 bits).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timespec {
    pub tv_sec: i64,
    pub tv_nsec: i64,
}

const NS: i64 = 1_000_000_000;

/// The `XrTime` of a CLOCK_MONOTONIC `timespec`, if it is a valid time.
pub fn to_time(t: Timespec) -> Result<i64, xr::Result> {
    if !(0..NS).contains(&t.tv_nsec) {
        return Err(xr::Result::ERROR_VALIDATION_FAILURE);
    }
    t.tv_sec
        .checked_mul(NS)
        .and_then(|s| s.checked_add(t.tv_nsec))
        .filter(|&ns| ns > 0)
        .ok_or(xr::Result::ERROR_TIME_INVALID)
}

/// The CLOCK_MONOTONIC `timespec` of an `XrTime`.
pub fn to_timespec(time: i64) -> Result<Timespec, xr::Result> {
    if time <= 0 {
        return Err(xr::Result::ERROR_TIME_INVALID);
    }
    Ok(Timespec {
        tv_sec: time / NS,
        tv_nsec: time % NS,
    })
}

pub unsafe extern "system" fn convert_timespec_time_to_time_khr(
    instance: xr::Instance,
    timespec: *const Timespec,
    time: *mut xr::Time,
) -> xr::Result {
    guard("xrConvertTimespecTimeToTimeKHR", || {
        let timespec = non_null(timespec)?;
        let time = non_null_mut(time)?;
        registry()
            .instance(instance)?
            .require_extension(CONVERT_TIMESPEC_TIME)?;
        // SAFETY: non-null, the application's timespec.
        let t = to_time(unsafe { *timespec })?;
        // SAFETY: non-null output.
        unsafe { time.write(xr::Time::from_nanos(t)) };
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn convert_time_to_timespec_time_khr(
    instance: xr::Instance,
    time: xr::Time,
    timespec: *mut Timespec,
) -> xr::Result {
    guard("xrConvertTimeToTimespecTimeKHR", || {
        let timespec = non_null_mut(timespec)?;
        registry()
            .instance(instance)?
            .require_extension(CONVERT_TIMESPEC_TIME)?;
        let t = to_timespec(time.as_nanos())?;
        // SAFETY: non-null output.
        unsafe { timespec.write(t) };
        Ok(xr::Result::SUCCESS)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timespecs_and_times_convert_exactly_and_refuse_nonsense() {
        let t = Timespec {
            tv_sec: 39_022,
            tv_nsec: 760_563_578,
        };
        assert_eq!(to_time(t), Ok(39_022_760_563_578));
        assert_eq!(to_timespec(39_022_760_563_578), Ok(t));
        let bad = Timespec {
            tv_sec: 1,
            tv_nsec: NS,
        };
        assert_eq!(to_time(bad), Err(xr::Result::ERROR_VALIDATION_FAILURE));
        let zero = Timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        assert_eq!(to_time(zero), Err(xr::Result::ERROR_TIME_INVALID));
        let huge = Timespec {
            tv_sec: i64::MAX,
            tv_nsec: 0,
        };
        assert_eq!(to_time(huge), Err(xr::Result::ERROR_TIME_INVALID));
        assert_eq!(to_timespec(0), Err(xr::Result::ERROR_TIME_INVALID));
    }
}
