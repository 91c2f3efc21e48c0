//! Partial TOML configs: a user's file names only the keys it changes, merged over the
//! serialised defaults before deserialisation, so nested config structs that require every
//! field (`deny_unknown_fields`, no per-field defaults) can still be configured one key at a time.

/// Overwrites `base` with the keys of `user`, recursing into tables present in both; keys
/// unknown to `base` are kept so that deserialisation rejects them by name.
pub fn merge_over(base: &mut toml::Table, user: toml::Table) {
    for (key, uv) in user {
        match (base.get_mut(&key), uv) {
            (Some(toml::Value::Table(bt)), toml::Value::Table(ut)) => merge_over(bt, ut),
            (_, uv) => {
                base.insert(key, uv);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nested_keys_override_and_unknown_keys_survive() {
        let mut base: toml::Table = "a = 1\n[t]\nx = 1\ny = 2\n".parse().unwrap();
        let user: toml::Table = "[t]\ny = 5\nz = 9\n".parse().unwrap();
        merge_over(&mut base, user);
        assert_eq!(base["a"].as_integer(), Some(1));
        assert_eq!(base["t"]["x"].as_integer(), Some(1));
        assert_eq!(base["t"]["y"].as_integer(), Some(5));
        assert_eq!(base["t"]["z"].as_integer(), Some(9));
    }
}
