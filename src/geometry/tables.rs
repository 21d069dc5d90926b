//! Tables built once per key and kept (a beam layout's directions, a bin width's cell bins):
//! a site's scans share a few layouts, and the tables are dear to build and cheap to keep.

/// At most `cap` tables, the oldest dropped for a new one.
#[derive(Debug)]
pub struct Tables<K, V> {
    kept: Vec<(K, V)>,
    cap: usize,
}

impl<K: PartialEq, V: Clone> Tables<K, V> {
    pub const fn new(cap: usize) -> Self {
        Tables {
            kept: Vec::new(),
            cap,
        }
    }

    /// The table for `key`, built by `make` when it is not kept.
    pub fn get(&mut self, key: K, make: impl FnOnce() -> V) -> V {
        if let Some((_, table)) = self.kept.iter().find(|(k, _)| *k == key) {
            return table.clone();
        }
        let table = make();
        if self.kept.len() >= self.cap {
            self.kept.remove(0);
        }
        if self.cap > 0 {
            self.kept.push((key, table.clone()));
        }
        table
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_table_is_built_once_and_the_oldest_goes_first() {
        let built = std::cell::Cell::new(0);
        let mut tables = Tables::new(2);
        let mut get = |k: u32| {
            tables.get(k, || {
                built.set(built.get() + 1);
                k * 10
            })
        };
        assert_eq!(get(1), 10);
        assert_eq!(get(1), 10);
        assert_eq!(get(2), 20);
        assert_eq!(get(3), 30);
        assert_eq!(get(2), 20);
        assert_eq!(get(1), 10, "1 went for 3, built again");
        assert_eq!(built.get(), 4);
    }
}
