#![no_main]
//! Fuzz target: see parsers.rs.

#[path = "parsers.rs"]
mod parsers;

libfuzzer_sys::fuzz_target!(|data: &[u8]| parsers::plan_json(data));
