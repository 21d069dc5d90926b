//! Numbers as a person reads them in messages and on the console. Pure: values in, text out.

use std::time::Duration;

/// A duration with its unit, rounded to what a person needs: `0.4 ms`, `75 ms`, `1.2 s`,
/// `42 s`, `3 min 05 s`, `2 h 01 min`. (`{:?}` would print `75.156576ms`.)
pub fn duration(d: Duration) -> String {
    let s = d.as_secs_f64();
    let ms = s * 1e3;
    if ms < 9.95 {
        format!("{ms:.1} ms")
    } else if ms < 999.5 {
        format!("{ms:.0} ms")
    } else if s < 9.95 {
        format!("{s:.1} s")
    } else if s < 59.5 {
        format!("{s:.0} s")
    } else {
        let whole = s.round() as u64;
        if whole < 3600 {
            format!("{} min {:02} s", whole / 60, whole % 60)
        } else {
            format!("{} h {:02} min", whole / 3600, whole % 3600 / 60)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(v: f64) -> String {
        duration(Duration::from_secs_f64(v / 1e3))
    }

    #[test]
    fn durations_read_naturally() {
        assert_eq!(ms(0.0), "0.0 ms");
        assert_eq!(ms(0.4), "0.4 ms");
        assert_eq!(ms(9.94), "9.9 ms");
        assert_eq!(ms(9.96), "10 ms");
        assert_eq!(ms(75.156576), "75 ms");
        assert_eq!(ms(999.4), "999 ms");
        assert_eq!(ms(999.6), "1.0 s");
        assert_eq!(ms(1_234.0), "1.2 s");
        assert_eq!(ms(9_960.0), "10 s");
        assert_eq!(ms(42_000.0), "42 s");
        assert_eq!(ms(59_600.0), "1 min 00 s");
        assert_eq!(ms(185_000.0), "3 min 05 s");
        assert_eq!(ms(7_290_000.0), "2 h 01 min");
    }
}
