//! CCSDS Orbit Ephemeris Message export (being written).
