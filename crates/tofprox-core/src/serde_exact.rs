//! Fixed-length arrays read from configuration files with their length checked: serde's
//! `[T; N]` reads N elements and silently drops the rest of a longer array
//! (`roi_origin = [0, 0, 99, "junk"]` would read as `[0, 0]`). Use with
//! `#[serde(deserialize_with = "tofprox_core::serde_exact::array")]`.

use serde::de::{Deserialize, Deserializer, Error};

/// Exactly `N` elements, else an `invalid_length` error saying how many were given.
pub fn array<'de, D, T, const N: usize>(d: D) -> Result<[T; N], D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    let v: Vec<T> = Vec::deserialize(d)?;
    let n = v.len();
    v.try_into()
        .map_err(|_| D::Error::invalid_length(n, &format!("exactly {N} elements").as_str()))
}

/// [`array()`] for an optional field: use with `#[serde(default, deserialize_with = …)]`
/// (absent: `None`; present: exactly `N` elements).
pub fn option_array<'de, D, T, const N: usize>(d: D) -> Result<Option<[T; N]>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    array(d).map(Some)
}

/// A list of fixed-length arrays, each of exactly `N` elements (`[[1, 2], [3, 4]]`).
pub fn vec_of_arrays<'de, D, T, const N: usize>(d: D) -> Result<Vec<[T; N]>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    struct Exact<T, const N: usize>([T; N]);
    impl<'de, T: Deserialize<'de>, const N: usize> Deserialize<'de> for Exact<T, N> {
        fn deserialize<D2: Deserializer<'de>>(d: D2) -> Result<Self, D2::Error> {
            array(d).map(Exact)
        }
    }
    let v: Vec<Exact<T, N>> = Vec::deserialize(d)?;
    Ok(v.into_iter().map(|e| e.0).collect())
}

#[cfg(test)]
mod tests {
    #[derive(serde::Deserialize, Debug)]
    struct Pair {
        #[serde(deserialize_with = "super::array")]
        p: [usize; 2],
    }

    #[derive(serde::Deserialize, Debug)]
    struct Optional {
        #[serde(default, deserialize_with = "super::option_array")]
        roi: Option<[usize; 4]>,
        #[serde(default, deserialize_with = "super::vec_of_arrays")]
        writes: Vec<[u16; 2]>,
    }

    #[test]
    fn optional_and_listed_arrays_have_exactly_n_elements() {
        let none: Optional = toml::from_str("").unwrap();
        assert_eq!((none.roi, none.writes.len()), (None, 0));
        let ok: Optional = toml::from_str("roi = [1, 2, 3, 4]\nwrites = [[1, 2], [3, 4]]").unwrap();
        assert_eq!(ok.roi, Some([1, 2, 3, 4]));
        assert_eq!(ok.writes, vec![[1, 2], [3, 4]]);
        for bad in [
            "roi = [10, 10, 20, 20, \"junk\", {x = 1}]",
            "roi = [10, 10, 20, 20, 1, 2]",
            "roi = [10, 10, 20, 20, 30]",
            "roi = [10, 10, 20]",
            "writes = [[1, 2, 3]]",
            "writes = [[1, 2], [3]]",
        ] {
            let e = toml::from_str::<Optional>(bad).unwrap_err();
            // a wrong element type is named as such; a wrong count as the count
            assert!(
                e.message().contains("exactly") || e.message().contains("invalid type"),
                "{bad}: {e}"
            );
        }
    }

    #[test]
    fn exactly_n_elements() {
        let ok: Pair = toml::from_str("p = [3, 4]").unwrap();
        assert_eq!(ok.p, [3, 4]);
        for bad in ["p = [3, 4, 5]", "p = [3]", "p = [3, 4, \"junk\"]", "p = []"] {
            let e = toml::from_str::<Pair>(bad).unwrap_err();
            assert!(e.to_string().contains("p"), "{bad}: {e}");
        }
        let e = toml::from_str::<Pair>("p = [3, 4, 5]").unwrap_err();
        assert!(e.message().contains("exactly 2 elements"), "{e}");
    }
}
