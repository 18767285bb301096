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

#[cfg(test)]
mod tests {
    #[derive(serde::Deserialize, Debug)]
    struct Pair {
        #[serde(deserialize_with = "super::array")]
        p: [usize; 2],
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
