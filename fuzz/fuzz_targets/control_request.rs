//! Arbitrary bytes as a control-socket stream: framing with the request cap, then the request
//! parser. No panic; a frame is never longer than the cap; a request that parses re-serializes
//! to JSON that parses to the same request.
#![no_main]

use infraloc::control::{read_frame, write_frame, Request, MAX_REQUEST_BYTES};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut r = data;
    while let Ok(Some(frame)) = read_frame(&mut r, MAX_REQUEST_BYTES) {
        assert!(frame.len() <= MAX_REQUEST_BYTES as usize);
        if let Ok(req) = serde_json::from_slice::<Request>(&frame) {
            let text = serde_json::to_vec(&req).unwrap();
            let mut framed = Vec::new();
            write_frame(&mut framed, &text).unwrap();
            let back = read_frame(&mut &framed[..], MAX_REQUEST_BYTES)
                .unwrap()
                .unwrap();
            assert_eq!(serde_json::from_slice::<Request>(&back).unwrap(), req);
        }
    }
});
