//! The Function Description Information (FDI Standard): the XML of space 0xFA that tells a
//! throttle which functions a train has and what they are called.

use alloc::string::String;
use core::fmt::Write as _;

use crate::memconfig::ReadOnlySpace;

/// How a function behaves on a throttle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum FunctionKind {
    /// On until switched off (a headlight).
    #[default]
    Binary,
    /// On while the key is held (a horn).
    Momentary,
}

/// One function of the FDI: its number (F0 is 0), name and kind.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FunctionName {
    /// The function number, the address in space 0xF9.
    pub number: u32,
    /// What a throttle shows.
    pub name: String,
    /// Binary or momentary.
    pub kind: FunctionKind,
}

/// Writes `text` with the five XML escapes.
fn escaped(out: &mut String, text: &str) {
    for c in text.chars() {
        match c {
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '&' => out.push_str("&amp;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
}

/// The FDI document of `functions`, in the order given: one segment, one group, each
/// function with its kind, name and number. The segment's `space` and `origin` and the
/// function's `size` are reserved and omitted, as FDI Standard §5.1.2 and §5.1.4 ask of new
/// implementations (their defaults are space 0xF9, origin 0, size 1).
pub fn fdi_xml(functions: &[FunctionName]) -> String {
    let mut xml = String::from(
        "<?xml version=\"1.0\"?>\n<fdi xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\" \
         xsi:noNamespaceSchemaLocation=\"https://openlcb.org/schema/fdi/1/1/fdi.xsd\">\n\
         <segment>\n<group>\n<name>Functions</name>\n",
    );
    for function in functions {
        let kind = match function.kind {
            FunctionKind::Binary => "binary",
            FunctionKind::Momentary => "momentary",
        };
        let _ = write!(xml, "<function kind=\"{kind}\">\n<name>");
        escaped(&mut xml, &function.name);
        let _ = writeln!(xml, "</name>\n<number>{}</number>\n</function>", function.number);
    }
    xml.push_str("</group>\n</segment>\n</fdi>\n");
    xml
}

/// Space 0xFA for `functions`: the FDI and the NUL that ends it.
pub fn fdi_space(functions: &[FunctionName]) -> ReadOnlySpace {
    ReadOnlySpace::cdi(&fdi_xml(functions))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_escaped_and_numbered() {
        let xml = fdi_xml(&[
            FunctionName { number: 0, name: "Headlight".into(), kind: FunctionKind::Binary },
            FunctionName { number: 2, name: "Horn <&>".into(), kind: FunctionKind::Momentary },
        ]);
        assert!(xml.starts_with("<?xml version=\"1.0\"?>"));
        assert!(xml.contains("<name>Headlight</name>\n<number>0</number>"));
        assert!(xml.contains("kind=\"momentary\">\n<name>Horn &lt;&amp;&gt;</name>\n<number>2</number>"));
    }
}
