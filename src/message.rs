//! The one-line form of error text for people: numbers mjsafe printed in full (a 1e300 is 301
//! digits with `{}`) shortened, what the user wrote kept as written. Every error a person
//! reads goes through it: the top-level error line, and the errors sweep rows and falsification
//! candidates keep in their summaries.

/// The most characters a number is shown with before it is shortened: every f64 below 1e21 and
/// every u64 print in full (they are exact and readable), a 1e300 does not.
pub const LONGEST_NUMBER: usize = 21;

/// `text` with every number of more than [`LONGEST_NUMBER`] characters that mjsafe formatted
/// (e.g. a 1e300 printed in full) written in scientific notation. What the user wrote is quoted verbatim:
/// digits that are part of a word or a path (`run-12345678901234567.mcap`), a value right
/// after `=` (an echoed `--set KEY=VALUE`), and a whole number between backticks (an integer
/// literal as typed; a float between backticks is the parser's rendering of it and is
/// shortened).
pub fn shorten_numbers(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut quoted = false;
    // The last character written.
    let mut previous: Option<char> = None;
    let mut rest = text;
    while let Some(c) = rest.chars().next() {
        if !c.is_ascii_digit() {
            quoted ^= c == '`';
            out.push(c);
            previous = Some(c);
            rest = &rest[c.len_utf8()..];
            continue;
        }
        let mut len = rest
            .char_indices()
            .find(|&(i, c)| {
                !(c.is_ascii_digit() || (c == '.' && rest[i + 1..].starts_with(|d: char| d.is_ascii_digit())))
            })
            .map_or(rest.len(), |(i, _)| i);
        // An exponent (`e300`, `e-16`) belongs to the number.
        let exponent = rest[len..]
            .strip_prefix(['e', 'E'])
            .map(|e| e.strip_prefix(['-', '+']).unwrap_or(e));
        if let Some(digits) = exponent.filter(|e| e.starts_with(|d: char| d.is_ascii_digit())) {
            let exponent_digits = digits.find(|d: char| !d.is_ascii_digit()).unwrap_or(digits.len());
            len = rest.len() - digits.len() + exponent_digits;
        }
        let (number, after) = rest.split_at(len);
        let mut next = after.chars();
        let in_word = previous.is_some_and(|c| c.is_alphanumeric() || matches!(c, '/' | '_' | '.' | '\\'))
            || match next.next() {
                None => false,
                Some('.') => next.next().is_some_and(char::is_alphanumeric),
                Some(c) => c.is_alphanumeric() || matches!(c, '/' | '_'),
            };
        let as_typed = in_word || previous == Some('=') || (quoted && !number.contains('.'));
        match number.parse::<f64>() {
            Ok(x) if number.len() > LONGEST_NUMBER && !as_typed => out.push_str(&format!("{x:.6e}")),
            _ => out.push_str(number),
        }
        previous = number.chars().last();
        rest = after;
    }
    out
}

/// A serde message in the scenario's terms instead of Rust's: no type names
/// ("untagged enum DelayProfile", "struct VehicleSpec"), TOML words for sequences and maps.
pub fn plain_serde_message(message: &str) -> String {
    let message = message.trim().replace('\n', " ");
    let message = message.as_str();
    if message.contains("untagged enum DelayProfile") {
        return "expected a delay in seconds (a number >= 0) or a table { profile = \"cosine_prediction\" | \"rational\" | \"table\", … }".into();
    }
    let mut out = String::with_capacity(message.len());
    let mut words = message.split(' ').peekable();
    while let Some(word) = words.next() {
        let next_is_type = words.peek().is_some_and(|w| {
            w.starts_with(|c: char| c.is_ascii_uppercase()) && w.chars().all(|c| c.is_alphanumeric() || c == ',')
        });
        let replacement = match word {
            "struct" | "map" if next_is_type => Some("a table"),
            "enum" if next_is_type => Some("one of the documented names"),
            "untagged" | "internally" | "tagged" if words.peek().is_some_and(|w| *w == "enum" || *w == "tagged") => {
                continue;
            }
            _ => None,
        };
        if !out.is_empty() {
            out.push(' ');
        }
        match replacement {
            Some(text) => {
                out.push_str(text);
                // The type name, keeping trailing punctuation.
                let name = words.next().unwrap_or_default();
                out.extend(name.chars().filter(|c| !c.is_alphanumeric()));
            }
            None => out.push_str(word),
        }
    }
    let mut out = out
        .replace("a sequence", "an array")
        .replace("a map", "a table")
        .replace("type: map", "type: table")
        .replace("type: sequence", "type: array")
        .replace("expected f64", "expected a number")
        .replace("expected f32", "expected a number")
        // serde names the wide type an out-of-range integer was read as ("`…` as i128").
        .replace("` as i128", "`")
        .replace("` as u128", "`");
    for int in ["u8", "u16", "u32", "u64", "usize"] {
        out = out.replace(&format!("expected {int}"), "expected a whole number >= 0");
    }
    for int in ["i8", "i16", "i32", "i64", "isize"] {
        out = out.replace(&format!("expected {int}"), "expected a whole number");
    }
    // toml repeats the key the message is already prefixed with.
    if let Some(at) = out.rfind(" in `") {
        if out.ends_with('`') {
            out.truncate(at);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::shorten_numbers;

    #[test]
    fn long_numbers_mjsafe_formatted_are_shortened_and_the_users_text_is_not() {
        let huge = format!("{}", 1e300);
        let tiny = format!("{}", -1e-300);
        // Numbers mjsafe formatted: shortened, exponent included.
        assert_eq!(
            shorten_numbers(&format!("found {huge}, clearance {tiny} m")),
            "found 1.000000e300, clearance -1.000000e-300 m"
        );
        assert_eq!(
            shorten_numbers("gains [1.9999999999999998e300, 2.220446049250313e-16]"),
            "gains [2.000000e300, 2.220446049250313e-16]"
        );
        assert_eq!(shorten_numbers(&format!("l0 = {huge}")), "l0 = 1.000000e300");
        assert_eq!(
            shorten_numbers(&format!("floating point `{huge}.0`")),
            "floating point `1.000000e300`"
        );
        // What the user wrote: paths, an echoed --set value, an integer literal in backticks.
        for verbatim in [
            "/tmp/run-12345678901234567.mcap: cannot read log",
            "/tmp/12345678901234567/s.toml: key `duration`",
            "s12345678901234567.toml",
            "x 12345678901234567 y.toml: key `duration`",
            "invalid type: string \"run 12345678901234567 s\"",
            "--set seed=18446744073709551615: `18446744073709551615` is not a TOML value",
            "found 12, 3.5 and 1e300",
        ] {
            assert_eq!(shorten_numbers(verbatim), verbatim);
        }
    }
}
