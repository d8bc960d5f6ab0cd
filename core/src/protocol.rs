//! Serial protocol (firmware issue).
