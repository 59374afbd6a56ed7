//! The commands as typed jobs: what `defocus render`, `defocus blur` and `defocus compare` do,
//! callable from a program with plain values in and out. The command line parses its flags
//! into these structs and calls them; the Python package builds the same structs from its
//! keyword arguments. The jobs never print: the lines a command shows go to a `notes` sink,
//! progress to a callback, and results are returned.
//!
//! - [`render`]: a scene through the thin lens with one method ([`render::RenderJob`]).
//! - [`blur`]: a rendered colour image with a depth pass ([`blur::BlurJob`]).
//! - [`report`]: every method against the reference as an HTML page and JSON
//!   ([`report::write`]).
//! - [`sequence`]: `render` and `blur` over frame sequences ([`sequence::blur`],
//!   [`sequence::render`]).
//! - [`mod@bench`]: the GPU methods timed warm on the built-in scenes, as JSON
//!   ([`bench::run`]).
//! - [`flags`]: the flags they share and their parsers.
//! - [`grid`]: the report's contact sheet of every method's image with its numbers.

pub mod bench;
pub mod blur;
pub mod flags;
pub mod grid;
pub mod render;
pub mod report;
pub mod sequence;
