//! Closed sets of values that users pick by name in configs and on the command line: the model presets
//! here, the synthetic subjects' presets, the evaluation splits. One trait gives each its parsing, its
//! error (naming the set and every name it has) and its display; [`by_name!`](crate::by_name) writes the
//! `FromStr` and `Display` impls that Rust's orphan rule does not let a blanket impl provide.

/// A closed set of values, each with the name users give it.
pub trait Named: Copy + PartialEq + 'static {
    /// What the set is called in messages, e.g. "model preset".
    const KIND: &'static str;

    /// Every value, in the order lists and help show them.
    fn all() -> &'static [Self];

    /// The value's name.
    fn name(self) -> &'static str;

    /// The value called `name`.
    fn from_name(name: &str) -> Result<Self, UnknownName> {
        Self::all()
            .iter()
            .copied()
            .find(|v| v.name() == name)
            .ok_or_else(|| UnknownName {
                kind: Self::KIND,
                given: name.to_string(),
                names: Self::all().iter().map(|v| v.name()).collect(),
            })
    }
}

/// A name that is none of a set's.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown {kind} '{given}': expected one of {}", names.join(", "))]
pub struct UnknownName {
    pub kind: &'static str,
    pub given: String,
    pub names: Vec<&'static str>,
}

/// `FromStr` (by [`Named::from_name`]) and `Display` (by [`Named::name`]) for a [`Named`] type.
#[macro_export]
macro_rules! by_name {
    ($t:ty) => {
        impl ::std::str::FromStr for $t {
            type Err = $crate::named::UnknownName;

            fn from_str(s: &str) -> Result<Self, Self::Err> {
                <$t as $crate::named::Named>::from_name(s)
            }
        }

        impl ::std::fmt::Display for $t {
            fn fmt(&self, f: &mut ::std::fmt::Formatter<'_>) -> ::std::fmt::Result {
                f.write_str(<$t as $crate::named::Named>::name(*self))
            }
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Colour {
        Red,
        Green,
    }

    impl Named for Colour {
        const KIND: &'static str = "colour";

        fn all() -> &'static [Self] {
            &[Colour::Red, Colour::Green]
        }

        fn name(self) -> &'static str {
            match self {
                Colour::Red => "red",
                Colour::Green => "green",
            }
        }
    }

    crate::by_name!(Colour);

    #[test]
    fn names_parse_back_and_others_are_refused_naming_every_name() {
        for c in Colour::all() {
            assert_eq!(c.to_string().parse::<Colour>(), Ok(*c));
        }
        let err = "blue".parse::<Colour>().unwrap_err();
        assert_eq!(
            err.to_string(),
            "unknown colour 'blue': expected one of red, green"
        );
    }
}
