//! tofprox sensor bridge: USB transport, CX3 protocol, sensor driver, emulated device
