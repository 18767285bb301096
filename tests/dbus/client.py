#!/usr/bin/python3
"""An independent D-Bus client of tofproxd (dbus-python + GLib, the stack
iio-sensor-proxy clients use). Prints one JSON object per line on stdout.

Modes:
  native   claim org.tofprox.Proximity1 proximity, report Near changes
           (--depth: claim depth too and report DepthFrame signals;
            --watch-depth: report DepthFrame signals without claiming depth)
  compat   act like an iio-sensor-proxy client: claim accelerometer, light,
           proximity and compass on net.hadess.SensorProxy, report ProximityNear
  own      own a bus name (a stand-in for a running iio-sensor-proxy)
  stress   N concurrent connections claiming/releasing at random for S seconds,
           some of them dropping off the bus without releasing
"""
import argparse
import json
import random
import sys
import time

import dbus
import dbus.mainloop.glib
from gi.repository import GLib

T0 = time.monotonic()


def emit(**kw):
    kw["t"] = round(time.monotonic() - T0, 3)
    print(json.dumps(kw, default=str), flush=True)


def plain(v):
    if isinstance(v, dbus.Boolean):
        return bool(v)
    if isinstance(v, (dbus.Double,)):
        return float(v)
    if isinstance(v, (dbus.Byte, dbus.Int16, dbus.Int32, dbus.Int64, dbus.UInt16, dbus.UInt32, dbus.UInt64)):
        return int(v)
    if isinstance(v, dbus.String):
        return str(v)
    return str(v)


def props_dict(d):
    return {str(k): plain(v) for k, v in d.items()}


def interfaces(bus, name, path, iface_name):
    """(the interface, its org.freedesktop.DBus.Properties) of object `path`."""
    obj = bus.get_object(name, path)
    return dbus.Interface(obj, iface_name), dbus.Interface(obj, "org.freedesktop.DBus.Properties")


def watch_properties(bus, path):
    """Report every PropertiesChanged signal of object `path`."""
    def changed(iface_name, changed, invalidated):
        emit(event="changed", interface=str(iface_name), props=props_dict(changed))

    bus.add_signal_receiver(changed, signal_name="PropertiesChanged",
                            dbus_interface="org.freedesktop.DBus.Properties",
                            path=path)


def native(bus, args):
    iface, props = interfaces(bus, "org.tofprox.Proximity1", "/org/tofprox/Proximity1",
                              "org.tofprox.Proximity1")
    watch_properties(bus, "/org/tofprox/Proximity1")
    if args.depth or args.watch_depth:
        # --watch-depth: listen for DepthFrame without claiming depth (an outsider)
        def depth(ts, w, h, d, a):
            emit(event="depth", width=int(w), height=int(h), bytes=len(d))
        bus.add_signal_receiver(depth, signal_name="DepthFrame", dbus_interface="org.tofprox.Proximity1",
                                path="/org/tofprox/Proximity1")
    if args.depth:
        iface.ClaimDepth()
    iface.ClaimProximity(timeout=30)
    allp = props.GetAll("org.tofprox.Proximity1")
    emit(event="claimed", unique=bus.get_unique_name(), props=props_dict(allp))


def compat(bus, args):
    iface, props = interfaces(bus, "net.hadess.SensorProxy", "/net/hadess/SensorProxy",
                              "net.hadess.SensorProxy")
    ciface, cprops = interfaces(bus, "net.hadess.SensorProxy", "/net/hadess/SensorProxy/Compass",
                                "net.hadess.SensorProxy.Compass")
    watch_properties(bus, "/net/hadess/SensorProxy")
    iface.ClaimAccelerometer()
    iface.ClaimLight()
    iface.ClaimProximity(timeout=30)
    ciface.ClaimCompass()
    allp = props.GetAll("net.hadess.SensorProxy")
    callp = cprops.GetAll("net.hadess.SensorProxy.Compass")
    emit(event="claimed", unique=bus.get_unique_name(),
         props=props_dict(allp),
         compass=props_dict(callp))
    if args.release_after:
        def release():
            iface.ReleaseAccelerometer()
            iface.ReleaseLight()
            iface.ReleaseProximity()
            ciface.ReleaseCompass()
            emit(event="released")
            return False
        GLib.timeout_add(int(args.release_after * 1000), release)


def own(bus, args):
    reply = bus.request_name(args.name, dbus.bus.NAME_FLAG_DO_NOT_QUEUE)
    emit(event="owned", name=args.name, reply=int(reply))


def stress(address, args, loop):
    rnd = random.Random(args.seed)
    conns = [None] * args.clients
    stats = {"calls": 0, "errors": 0, "drops": 0}

    def connect(i):
        conns[i] = dbus.bus.BusConnection(address)

    def act(i):
        c = conns[i]
        if c is None:
            connect(i)
            c = conns[i]
        r = rnd.random()
        if r < 0.1:
            # drop off the bus without releasing
            c.close()
            conns[i] = None
            stats["drops"] += 1
        else:
            obj = c.get_object("org.tofprox.Proximity1", "/org/tofprox/Proximity1", introspect=False)
            method = "ClaimProximity" if r < 0.55 else "ReleaseProximity"

            def ok(*_):
                stats["calls"] += 1

            def err(e):
                stats["errors"] += 1
                emit(event="error", error=str(e))
            obj.get_dbus_method(method, "org.tofprox.Proximity1")(reply_handler=ok, error_handler=err, timeout=30)
        GLib.timeout_add(rnd.randint(5, 200), act, i)
        return False

    for i in range(args.clients):
        connect(i)
        GLib.timeout_add(rnd.randint(0, 200), act, i)

    def finish():
        for i, c in enumerate(conns):
            if c is not None:
                c.close()
                conns[i] = None
        emit(event="stress-done", **stats)
        loop.quit()
        return False
    GLib.timeout_add(int(args.seconds * 1000), finish)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=["native", "compat", "own", "stress"])
    ap.add_argument("--address", required=True)
    ap.add_argument("--timeout", type=float, default=60)
    ap.add_argument("--depth", action="store_true")
    ap.add_argument("--watch-depth", action="store_true")
    ap.add_argument("--name", default="net.hadess.SensorProxy")
    ap.add_argument("--release-after", type=float, default=0)
    ap.add_argument("--clients", type=int, default=100)
    ap.add_argument("--seconds", type=float, default=30)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    dbus.mainloop.glib.DBusGMainLoop(set_as_default=True)
    loop = GLib.MainLoop()
    try:
        if args.mode == "stress":
            stress(args.address, args, loop)
        else:
            bus = dbus.bus.BusConnection(args.address)
            {"native": native, "compat": compat, "own": own}[args.mode](bus, args)
    except dbus.exceptions.DBusException as e:
        emit(event="dbus-error", name=e.get_dbus_name(), message=e.get_dbus_message())
        sys.exit(1)
    GLib.timeout_add(int(args.timeout * 1000), loop.quit)
    loop.run()


if __name__ == "__main__":
    main()
