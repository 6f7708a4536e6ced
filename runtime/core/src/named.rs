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
    fn from_name(name: &str) -> Result<Self, String> {
        Self::ALL
            .iter()
            .copied()
            .find(|v| v.name() == name)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|v| v.name()).collect();
                format!("unknown value {name:?}; choose one of {}", names.join(", "))
            })
    }
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
        assert!(e.contains("red, green"), "{e}");
    }
}
