//! tofprox processing core: raw phase images to calibrated depth (thesis ch. 2.2, 3.3, 4.3)
