//! Choices a user names on the command line or in a report (a backend, a
//! precision, a method): one list of names per type, so the binary builds
//! its parsers and help from the libraries' own lists and the libraries
//! need no command-line crate.

/// A closed set of named values.
pub trait Named: Sized + Copy + PartialEq + Send + Sync + 'static {
    /// Every value, in the order help lists them.
    const ALL: &'static [Self];
    /// The name a user types.
    fn name(self) -> &'static str;
    /// One line for `--help`.
    fn help(self) -> &'static str {
        ""
    }
    /// The value named `name`, or an error listing the choices.
    fn from_name(name: &str) -> Result<Self, UnknownName> {
        Self::ALL
            .iter()
            .copied()
            .find(|v| v.name() == name)
            .ok_or_else(|| UnknownName {
                name: name.to_string(),
                choices: Self::ALL.iter().map(|v| v.name()).collect(),
            })
    }
}

/// A name none of a [`Named`] type's values has; its message lists the
/// choices.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown value {name:?}; choose one of {}", choices.join(", "))]
pub struct UnknownName {
    pub name: String,
    pub choices: Vec<&'static str>,
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
        const ALL: &'static [Self] = &[Colour::Red, Colour::Green];
        fn name(self) -> &'static str {
            match self {
                Colour::Red => "red",
                Colour::Green => "green",
            }
        }
    }

    #[test]
    fn names_round_trip_and_unknown_ones_list_the_choices() {
        for c in Colour::ALL {
            assert_eq!(Colour::from_name(c.name()), Ok(*c));
        }
        let e = Colour::from_name("blue").expect_err("unknown");
        assert!(e.to_string().contains("red, green"), "{e}");
    }
}
