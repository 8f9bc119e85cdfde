//! The one caching policy for work bound to resources the caller may swap: a value
//! (dispatches and their bind groups) built for a key, the identities of what it binds,
//! and reused for as long as the same key comes back; a new key rebuilds it and drops the
//! old value. The denoiser's input packing (the caller's six buffers), the tracer's frame
//! dispatches (scene and mode) and the display (the two tensors it shows) use it; the
//! network's dispatches bind only tensors it owns and are built with it.

/// A value built for a key and kept while the key stays the same.
#[derive(Debug)]
pub struct Bound<K, V> {
    slot: Option<(K, V)>,
}

impl<K, V> Default for Bound<K, V> {
    fn default() -> Self {
        Self { slot: None }
    }
}

impl<K: PartialEq, V> Bound<K, V> {
    /// Nothing bound yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// The value for `key`: the kept one when it was built for an equal key, else the one
    /// `build` makes now (kept in its place; a failed build keeps nothing).
    pub fn get_or_build<E>(&mut self, key: K, build: impl FnOnce() -> Result<V, E>) -> Result<&V, E> {
        if !matches!(&self.slot, Some((k, _)) if *k == key) {
            self.slot = None;
            self.slot = Some((key, build()?));
        }
        Ok(&self.slot.as_ref().expect("set above").1)
    }

    /// The value bound last, if any.
    pub fn get(&self) -> Option<&V> {
        self.slot.as_ref().map(|(_, v)| v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rebuilds_only_for_a_new_key() {
        let mut b: Bound<u32, String> = Bound::new();
        let builds = std::cell::Cell::new(0);
        let mut get = |k: u32| {
            b.get_or_build(k, || {
                builds.set(builds.get() + 1);
                Ok::<_, ()>(format!("v{k}"))
            })
            .unwrap()
            .clone()
        };
        assert_eq!(get(1), "v1");
        assert_eq!(get(1), "v1");
        assert_eq!(get(2), "v2");
        assert_eq!(get(1), "v1");
        assert_eq!(builds.get(), 3);
        let e = b.get_or_build(5, || Err("broken"));
        assert_eq!(e.unwrap_err(), "broken");
        assert!(b.get().is_none(), "a failed build keeps nothing");
    }
}
