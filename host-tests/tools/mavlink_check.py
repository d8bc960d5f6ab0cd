#!/usr/bin/env python3
"""Decodes a captured MAVLink 2 stream (the firmware's raw serial output,
`cargo fw REC --protocol mavlink --capture FILE`) with pymavlink, the
reference implementation ground stations and companion computers use.

usage: mavlink_check.py CAPTURE

stdout, csv: a header, then one row per OBSTACLE_DISTANCE, as pymavlink
decoded it:
  time_usec,sysid,compid,frame,min_distance,max_distance,increment,increment_f,angle_offset,d0,...,d71
then one line of counts:
  # messages N bytes N receive_errors N bad_data N unknown N mavlink1 N seq_gaps N leftover_bytes N HEARTBEAT N ...
receive_errors is pymavlink's own counter; bad_data counts what its robust
parser refused (a bad CRC, a bad length, bytes outside any frame), unknown
frames whose id the common dialect does not know, seq_gaps the places where
a sender's sequence number does not step by one, leftover_bytes an
unfinished frame at the end. Exit status 1 when any of these is not zero.
"""

import collections
import sys

from pymavlink.dialects.v20 import common as dialect

FIELDS = ("time_usec", "sysid", "compid", "frame", "min_distance", "max_distance",
          "increment", "increment_f", "angle_offset")
BINS = 72


def main(path):
    with open(path, "rb") as capture:
        data = capture.read()
    mav = dialect.MAVLink(None)
    # Robust parsing turns every refused frame into MAVLink_bad_data
    # instead of raising on the first one, so all of them are counted.
    mav.robust_parsing = True
    messages = mav.parse_buffer(data) or []
    counts = collections.Counter()
    last_seq = {}
    out = sys.stdout
    out.write(",".join(FIELDS + tuple(f"d{j}" for j in range(BINS))) + "\n")
    for msg in messages:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            counts["bad_data"] += 1
            print(f"mavlink_check: bad data: {msg.reason}", file=sys.stderr)
            continue
        if isinstance(msg, dialect.MAVLink_unknown):
            counts["unknown"] += 1
            continue
        if msg.get_msgbuf()[0] != dialect.PROTOCOL_MARKER_V2:
            counts["mavlink1"] += 1
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        seq = msg.get_seq()
        if sender in last_seq and seq != (last_seq[sender] + 1) % 256:
            counts["seq_gaps"] += 1
        last_seq[sender] = seq
        counts[kind] += 1
        if kind == "OBSTACLE_DISTANCE":
            row = [msg.time_usec, sender[0], sender[1], msg.frame, msg.min_distance, msg.max_distance,
                   msg.increment, repr(msg.increment_f), repr(msg.angle_offset)]
            row += list(msg.distances)
            out.write(",".join(str(v) for v in row) + "\n")
    counts["leftover_bytes"] = mav.buf_len()
    summary = {
        "messages": mav.total_packets_received,
        "bytes": mav.total_bytes_received,
        "receive_errors": mav.total_receive_errors,
    }
    for key in ("bad_data", "unknown", "mavlink1", "seq_gaps", "leftover_bytes"):
        summary[key] = counts.pop(key, 0)
    summary.update(sorted(counts.items()))
    out.write("# " + " ".join(f"{k} {v}" for k, v in summary.items()) + "\n")
    faults = ("receive_errors", "bad_data", "unknown", "mavlink1", "seq_gaps", "leftover_bytes")
    return 1 if any(summary[k] for k in faults) else 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    sys.exit(main(sys.argv[1]))
