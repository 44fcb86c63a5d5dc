//! Procedural built-in scenes.
