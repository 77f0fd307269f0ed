//! Serde helpers for arrays of exactly N numbers: `[8, 12, 3, 5]` where two numbers are expected is an error
//! ("invalid length 4, expected exactly 2 numbers"), never silently `[8, 12]` (some formats' sequence readers
//! stop after the elements a fixed-size array asks for). Used with `#[serde(with = "…")]` on every fixed-length
//! field of the scenario schema.

use std::fmt;
use std::marker::PhantomData;

use glam::{DVec2, DVec3};
use serde::de::{Error, IgnoredAny, SeqAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

struct Exact<T, const N: usize>(PhantomData<T>);

impl<'de, T: Deserialize<'de> + Copy + Default, const N: usize> Visitor<'de> for Exact<T, N> {
    type Value = [T; N];

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "exactly {N} numbers")
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
        let mut out = [T::default(); N];
        for (i, slot) in out.iter_mut().enumerate() {
            *slot = seq.next_element()?.ok_or_else(|| A::Error::invalid_length(i, &self))?;
        }
        let mut extra = 0;
        while seq.next_element::<IgnoredAny>()?.is_some() {
            extra += 1;
        }
        if extra > 0 {
            return Err(A::Error::invalid_length(N + extra, &self));
        }
        Ok(out)
    }
}

/// Reads exactly `N` numbers.
///
/// # Errors
/// The format's error for a non-sequence, a non-number or a length other than `N`.
pub fn array<'de, D: Deserializer<'de>, const N: usize>(d: D) -> Result<[f64; N], D::Error> {
    d.deserialize_seq(Exact::<f64, N>(PhantomData))
}

/// `[f64; 2]`, exactly two numbers.
pub mod pair {
    use super::*;

    /// Reads exactly two numbers.
    ///
    /// # Errors
    /// See [`array()`].
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 2], D::Error> {
        array(d)
    }

    /// Writes the two numbers.
    ///
    /// # Errors
    /// The serializer's.
    pub fn serialize<S: Serializer>(v: &[f64; 2], s: S) -> Result<S::Ok, S::Error> {
        v.serialize(s)
    }
}

/// [`DVec3`], exactly three numbers.
pub mod dvec3 {
    use super::*;

    /// Reads exactly three numbers.
    ///
    /// # Errors
    /// See [`array()`].
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<DVec3, D::Error> {
        array::<D, 3>(d).map(DVec3::from_array)
    }

    /// Writes `[x, y, z]`.
    ///
    /// # Errors
    /// The serializer's.
    pub fn serialize<S: Serializer>(v: &DVec3, s: S) -> Result<S::Ok, S::Error> {
        v.to_array().serialize(s)
    }
}

/// `Option<DVec3>`, exactly three numbers when present.
pub mod opt_dvec3 {
    use super::*;

    /// Reads exactly three numbers.
    ///
    /// # Errors
    /// See [`array()`].
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<DVec3>, D::Error> {
        d.deserialize_option(OptionOf::<f64, 3>(PhantomData)).map(|v| v.map(DVec3::from_array))
    }

    /// Writes `[x, y, z]` or nothing.
    ///
    /// # Errors
    /// The serializer's.
    pub fn serialize<S: Serializer>(v: &Option<DVec3>, s: S) -> Result<S::Ok, S::Error> {
        v.map(|v| v.to_array()).serialize(s)
    }
}

/// `Option<DVec2>`, exactly two numbers when present.
pub mod opt_dvec2 {
    use super::*;

    /// Reads exactly two numbers.
    ///
    /// # Errors
    /// See [`array()`].
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<DVec2>, D::Error> {
        d.deserialize_option(OptionOf::<f64, 2>(PhantomData)).map(|v| v.map(DVec2::from_array))
    }

    /// Writes `[u, v]` or nothing.
    ///
    /// # Errors
    /// The serializer's.
    pub fn serialize<S: Serializer>(v: &Option<DVec2>, s: S) -> Result<S::Ok, S::Error> {
        v.map(|v| v.to_array()).serialize(s)
    }
}

/// `Vec<[f64; 4]>`: rows of exactly four numbers.
pub mod rows4 {
    use super::*;

    struct Rows;

    impl<'de> Visitor<'de> for Rows {
        type Value = Vec<[f64; 4]>;

        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str("a list of rows of exactly 4 numbers")
        }

        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
            let mut out = Vec::new();
            while let Some(Row(r)) = seq.next_element()? {
                out.push(r);
            }
            Ok(out)
        }
    }

    struct Row([f64; 4]);

    impl<'de> serde::Deserialize<'de> for Row {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            array(d).map(Row)
        }
    }

    /// Reads the rows.
    ///
    /// # Errors
    /// See [`array()`].
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<[f64; 4]>, D::Error> {
        d.deserialize_seq(Rows)
    }

    /// Writes the rows.
    ///
    /// # Errors
    /// The serializer's.
    pub fn serialize<S: Serializer>(v: &[[f64; 4]], s: S) -> Result<S::Ok, S::Error> {
        v.serialize(s)
    }
}

/// `Option<[usize; 2]>`, exactly two whole numbers when present.
pub mod opt_counts2 {
    use super::*;

    /// Reads nothing, or exactly two whole numbers.
    ///
    /// # Errors
    /// The format's error for a non-sequence, a value that is not a whole number ≥ 0, or a length other than 2.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[usize; 2]>, D::Error> {
        d.deserialize_option(OptionOf::<usize, 2>(PhantomData))
    }

    /// Writes the two numbers.
    ///
    /// # Errors
    /// The serializer's.
    pub fn serialize<S: Serializer>(v: &Option<[usize; 2]>, s: S) -> Result<S::Ok, S::Error> {
        v.serialize(s)
    }
}

struct OptionOf<T, const N: usize>(PhantomData<[T; N]>);

impl<'de, T: Deserialize<'de> + Copy + Default, const N: usize> Visitor<'de> for OptionOf<T, N> {
    type Value = Option<[T; N]>;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "exactly {N} numbers")
    }

    fn visit_none<E: Error>(self) -> Result<Self::Value, E> {
        Ok(None)
    }

    fn visit_unit<E: Error>(self) -> Result<Self::Value, E> {
        Ok(None)
    }

    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Self::Value, D::Error> {
        d.deserialize_seq(Exact::<T, N>(PhantomData)).map(Some)
    }
}

#[cfg(test)]
mod tests {
    use serde::Deserialize;

    #[derive(Deserialize, Debug)]
    struct S {
        #[serde(with = "super::dvec3")]
        v: glam::DVec3,
        #[serde(default, with = "super::opt_dvec2")]
        o: Option<glam::DVec2>,
        #[serde(with = "super::rows4")]
        r: Vec<[f64; 4]>,
    }

    #[test]
    fn exact_lengths_only() {
        let ok: S = toml::from_str("v = [1, 2, 3]\no = [1, 2]\nr = [[0, 1, 2, 3]]").unwrap();
        assert_eq!(ok.v.z, 3.0);
        assert_eq!(ok.o.unwrap().y, 2.0);
        assert_eq!(ok.r, vec![[0.0, 1.0, 2.0, 3.0]]);
        let no_o: S = toml::from_str("v = [1, 2, 3]\nr = []").unwrap();
        assert!(no_o.o.is_none());
        for bad in ["v = [1, 2, 3, 4]\nr = []", "v = [1, 2]\nr = []", "v = [1, 2, 3]\no = [1, 2, 3]\nr = []"] {
            let e = toml::from_str::<S>(bad).unwrap_err();
            assert!(e.message().contains("invalid length"), "{bad}: {e}");
        }
        assert!(toml::from_str::<S>("v = [1, 2, 3]\nr = [[0, 1, 2, 3, 4]]").is_err());
        assert!(serde_json::from_str::<S>(r#"{"v": [1, 2, 3, 4], "r": []}"#).is_err());
    }
}
