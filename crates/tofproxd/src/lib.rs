//! tofproxd: the low-power ToF proximity daemon on D-Bus (thesis 3.5.3, listing 4.11).
