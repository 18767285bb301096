//! tofprox model lab: compare the model with measurements and find the missing effect
