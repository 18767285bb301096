//! tofprox physical sensor model: scene to raw ADC codes with an effect catalogue
