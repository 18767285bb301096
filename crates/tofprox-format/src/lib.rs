//! tofprox file formats: recordings (version 1) and calibration sets
