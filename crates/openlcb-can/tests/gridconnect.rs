//! The GridConnect decoder fed every published frame whole, byte by byte and split at every
//! boundary, plus lower-case and short ids, whitespace, standard and remote frames, garbage,
//! truncated and over-long input.

mod common;

use common::published::all_frames;
use common::text;
use openlcb_can::gridconnect::{GridConnectDecoder, MAX_FRAME_TEXT};
use openlcb_can::{CanFrame, GridConnectError};

type Outcome = Result<String, GridConnectError>;

/// Feeds `pieces` one after the other and collects every outcome (frames as re-encoded text).
fn feed<'a>(decoder: &mut GridConnectDecoder, pieces: impl IntoIterator<Item = &'a [u8]>) -> Vec<Outcome> {
    let mut out = Vec::new();
    for piece in pieces {
        decoder.decode_all(piece, |r| out.push(r.map(|f: CanFrame| text(&f))));
    }
    out
}

fn decode(input: &str) -> Vec<Outcome> {
    feed(&mut GridConnectDecoder::new(), [input.as_bytes()])
}

fn frames(texts: &[&str]) -> Vec<Outcome> {
    texts.iter().map(|t| Ok(t.to_string())).collect()
}

#[test]
fn every_published_frame_whole_byte_by_byte_and_split_everywhere() {
    for published in all_frames() {
        let bytes = published.as_bytes();
        let expected = frames(&[published]);
        assert_eq!(decode(published), expected, "whole");
        assert_eq!(feed(&mut GridConnectDecoder::new(), bytes.chunks(1)), expected, "byte by byte");
        for cut in 0..=bytes.len() {
            let (head, tail) = bytes.split_at(cut);
            assert_eq!(feed(&mut GridConnectDecoder::new(), [head, tail]), expected, "{published} cut at {cut}");
        }
    }
}

#[test]
fn all_frames_in_one_stream_split_at_every_boundary() {
    let published: Vec<&str> = all_frames().collect();
    let stream = published.join("\r\n");
    let expected = frames(&published);
    let bytes = stream.as_bytes();
    for cut in 0..=bytes.len() {
        let (head, tail) = bytes.split_at(cut);
        let mut decoder = GridConnectDecoder::new();
        assert_eq!(feed(&mut decoder, [head, tail]), expected, "cut at {cut}");
        assert_eq!(decoder.stats().frames, published.len() as u64);
        assert!(!decoder.is_mid_frame());
    }
    assert_eq!(feed(&mut GridConnectDecoder::new(), bytes.chunks(1)), expected);
    assert_eq!(feed(&mut GridConnectDecoder::new(), bytes.chunks(7)), expected);
}

#[test]
fn accepts_lower_case_and_any_number_of_id_digits() {
    assert_eq!(decode(":x19cc8123n04560010000004;"), frames(&[":X19CC8123N04560010000004;"]));
    assert_eq!(decode(":X123N;"), frames(&[":X00000123N;"]));
    assert_eq!(decode(":X00000000019100123N050101012200;"), frames(&[":X19100123N050101012200;"]));
}

#[test]
fn tolerates_whitespace_between_frames() {
    let input = " \r\n:X10700123N;\n\n\t :X10700456N;\r\n";
    assert_eq!(decode(input), frames(&[":X10700123N;", ":X10700456N;"]));
}

#[test]
fn skips_and_counts_standard_and_remote_frames() {
    let mut decoder = GridConnectDecoder::new();
    let input = b":S72DNF0F1F2F3F4F5F6F7;:X10700123N;:X19100123R;:S123R;:X10700456N;";
    assert_eq!(feed(&mut decoder, [&input[..]]), frames(&[":X10700123N;", ":X10700456N;"]));
    let stats = decoder.stats();
    assert_eq!((stats.standard_ignored, stats.remote_ignored, stats.frames, stats.errors), (1, 2, 2, 0));
}

#[test]
fn garbage_is_reported_once_and_skipped_to_the_next_colon() {
    let out = decode("hello;world:X10700123N;junk\n:X10700456N;");
    assert_eq!(
        out,
        [
            Err(GridConnectError::Garbage { byte: b'h' }),
            Ok(":X10700123N;".to_string()),
            Err(GridConnectError::Garbage { byte: b'j' }),
            Ok(":X10700456N;".to_string()),
        ]
    );
}

#[test]
fn malformed_frames_give_typed_errors_and_the_next_frame_survives() {
    let good = ":X10700123N;";
    let cases: [(&str, GridConnectError); 8] = [
        (":Q10700123N;", GridConnectError::InvalidCharacter { byte: b'Q' }),
        (":X1070G123N;", GridConnectError::InvalidCharacter { byte: b'G' }),
        (":XN;", GridConnectError::MissingId),
        (":X20000000N;", GridConnectError::IdOutOfRange),
        (":S800N;", GridConnectError::IdOutOfRange),
        (":X10700123N123;", GridConnectError::OddDataDigits),
        (":X10700123N000102030405060708;", GridConnectError::TooManyDataBytes),
        (":X10700123N01 02;", GridConnectError::InvalidCharacter { byte: b' ' }),
    ];
    for (bad, error) in cases {
        let input = format!("{bad}{good}");
        assert_eq!(decode(&input), [Err(error), Ok(good.to_string())], "{bad}");
        // The same in pieces of one byte.
        let out = feed(&mut GridConnectDecoder::new(), input.as_bytes().chunks(1));
        assert_eq!(out, [Err(error), Ok(good.to_string())], "{bad} byte by byte");
    }
}

#[test]
fn truncated_frame_is_reported_when_the_next_one_starts() {
    let mut decoder = GridConnectDecoder::new();
    assert_eq!(feed(&mut decoder, [&b":X1070012"[..]]), []);
    assert!(decoder.is_mid_frame(), "a partial frame waits for more input");
    assert_eq!(
        feed(&mut decoder, [&b":X10700456N;"[..]]),
        [Err(GridConnectError::Truncated), Ok(":X10700456N;".to_string())]
    );
}

#[test]
fn over_long_frame_is_cut_off_and_the_decoder_resynchronises() {
    let long = format!(":X{};", "0".repeat(200));
    let input = format!("{long}:X10700123N;");
    let mut decoder = GridConnectDecoder::new();
    let out = feed(&mut decoder, input.as_bytes().chunks(3));
    assert_eq!(out, [Err(GridConnectError::TooLong), Ok(":X10700123N;".to_string())]);
    // Exactly the bound is still accepted (leading zeros pad the id).
    let padded = format!(":X{}10700123N;", "0".repeat(MAX_FRAME_TEXT - ":X10700123N;".len()));
    assert_eq!(padded.len(), MAX_FRAME_TEXT);
    assert_eq!(decode(&padded), frames(&[":X10700123N;"]));
    let one_more = format!(":X0{}", &padded[2..]);
    assert_eq!(decode(&one_more), [Err(GridConnectError::TooLong)]);
}
