//! Value parsers for the arguments every command shares, so that a bad value is a clap error
//! (exit status 2) that says which forms are accepted.

use std::net::SocketAddr;
use std::str::FromStr;

use openlcb_stream::NodeId;

/// The forms [`node_id`] accepts, for error messages and help.
pub(crate) const NODE_ID_FORMS: &str =
    "six hex bytes: 05.01.01.01.22.F1, 05:01:01:01:22:F1, 0501010122F1 or 0x0501010122F1";

/// A Node ID in any of the forms people paste (dots, colons, bare hex, `0x` hex); the reserved
/// ranges 00.xx.xx.xx.xx.xx and FF.xx.xx.xx.xx.xx are refused (never a real node's ID).
pub(crate) fn node_id(text: &str) -> Result<NodeId, String> {
    let id: NodeId = text.parse().map_err(|_| format!("expected {NODE_ID_FORMS}"))?;
    match id.to_bytes()[0] {
        0x00 | 0xFF => Err(format!("{id} is reserved (00.xx... and FF.xx... are never a node's ID)")),
        _ => Ok(id),
    }
}

/// A hub address, `HOST:PORT`; a missing port is named as such.
pub(crate) fn hub_addr(text: &str) -> Result<String, String> {
    if text.parse::<SocketAddr>().is_ok() {
        return Ok(text.to_string());
    }
    let has_port = text.rsplit_once(':').is_some_and(|(host, port)| !host.is_empty() && port.parse::<u16>().is_ok());
    if !has_port {
        return Err(format!("expected HOST:PORT (e.g. 127.0.0.1:12021); `{text}` has no port"));
    }
    // A host name is resolved when the command connects; only its form is checked here.
    Ok(text.to_string())
}

/// A count or a number of seconds that must be at least 1.
pub(crate) fn positive<T: FromStr + Default + PartialEq>(text: &str) -> Result<T, String> {
    match text.parse::<T>() {
        Ok(value) if value == T::default() => Err("must be at least 1".to_string()),
        Ok(value) => Ok(value),
        Err(_) => Err(format!("`{text}` is not a whole number")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_ids_in_every_pasted_form_parse_alike() {
        let dotted = node_id("05.01.01.01.22.F1").unwrap();
        for form in ["05:01:01:01:22:F1", "0501010122F1", "0x0501010122F1", "05.01.01.01.22.f1"] {
            assert_eq!(node_id(form).unwrap(), dotted, "{form}");
        }
    }

    #[test]
    fn reserved_node_ids_are_refused() {
        for reserved in ["00.00.00.00.00.00", "00.01.02.03.04.05", "FF.FF.FF.FF.FF.FF", "0xFF0000000001"] {
            assert!(node_id(reserved).unwrap_err().contains("reserved"), "{reserved}");
        }
        assert!(node_id("05.01").unwrap_err().contains("0x0501010122F1"));
    }

    #[test]
    fn a_hub_address_needs_a_port() {
        assert!(hub_addr("127.0.0.1").unwrap_err().contains("no port"));
        assert!(hub_addr("localhost").is_err());
        assert_eq!(hub_addr("127.0.0.1:12021").unwrap(), "127.0.0.1:12021");
        assert_eq!(hub_addr("[::1]:12021").unwrap(), "[::1]:12021");
        assert_eq!(hub_addr("hub.local:12021").unwrap(), "hub.local:12021");
    }

    #[test]
    fn zero_is_not_positive() {
        assert!(positive::<u64>("0").is_err());
        assert!(positive::<usize>("x").is_err());
        assert_eq!(positive::<u64>("5"), Ok(5));
    }
}
