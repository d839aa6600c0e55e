#!/usr/bin/env python3
"""The cohort report of workflows/cohort/Snakefile: one row per scan, as CSV and as HTML.

    cohort_report.py --out DIR --csv DIR/cohort.csv --html DIR/cohort.html ID [ID ...]

Reads, for each scan, DIR/studies/ID/: stages/*.json (the receipts of `flyover stage`),
manifest.json (each stage's report and wall time), coverage/coverage.json, centerline.json.
Every field it cannot find is written as "" (older or newer flyover versions add or drop
report fields); only a missing receipt or a failed one makes a scan "failed".
Standard library only. Exit 0 when the report is written, even with failed scans: a failed scan
is a row, not an error.
"""

import argparse
import csv
import html
import json
import math
import os
import sys

STAGES = ["ingest", "segment", "centerline", "mesh", "render"]

COLUMNS = [
    "id", "status", "failed_stage", "error",
    "lumen_volume_ml", "lumen_pieces", "collapses", "contacts", "rectal_tube",
    "centerline_length_mm", "bridged_mm",
    "coverage_flyover", "coverage_flyover_with_review", "coverage_flythrough_two_way", "missed_regions",
    "polyps", "voids",
    "time_total_s", "time_ingest_s", "time_segment_s", "time_centerline_s", "time_mesh_s", "time_render_s",
    "computed_stages", "warnings", "overview",
]


def load(path):
    """JSON of a file, or None when it is missing or unreadable."""
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def dig(obj, *keys):
    """obj[k0][k1]... or None."""
    for k in keys:
        if isinstance(obj, dict) and k in obj:
            obj = obj[k]
        elif isinstance(obj, list) and isinstance(k, int) and -len(obj) <= k < len(obj):
            obj = obj[k]
        else:
            return None
    return obj


def count(value):
    """A count from a field that may be a number, a list, or an object with a count."""
    if value is None or isinstance(value, bool):
        return "" if value is None else int(value)
    if isinstance(value, (int, float)):
        return value
    if isinstance(value, list):
        return len(value)
    if isinstance(value, dict):
        for k in ("count", "n", "total"):
            if isinstance(value.get(k), (int, float)):
                return value[k]
        for k in ("items", "list", "contacts", "regions"):
            if isinstance(value.get(k), list):
                return len(value[k])
        if "detected" in value or "present" in value:
            return int(bool(value.get("detected", value.get("present"))))
    return ""


def fraction(value):
    """A coverage fraction from a number or an object with "fraction"."""
    if isinstance(value, dict):
        value = value.get("fraction")
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return round(float(value), 6)
    return ""


def number(value, digits=3):
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return round(float(value), digits)
    return ""


def find_key(obj, key):
    """Every value of `key` anywhere in obj (depth-first)."""
    found = []
    if isinstance(obj, dict):
        for k, v in obj.items():
            if k == key:
                found.append(v)
            else:
                found += find_key(v, key)
    elif isinstance(obj, list):
        for v in obj:
            found += find_key(v, key)
    return found


def scan_row(out_dir, sid):
    study = os.path.join(out_dir, "studies", sid)
    row = {c: "" for c in COLUMNS}
    row["id"] = sid

    receipts = {s: load(os.path.join(study, "stages", s + ".json")) for s in STAGES}
    failed = [s for s in STAGES if isinstance(receipts[s], dict) and receipts[s].get("status") == "failed"]
    if failed:
        row["status"] = "failed"
        row["failed_stage"] = failed[0]
        row["error"] = str(receipts[failed[0]].get("error", "")).splitlines()[0] if receipts[failed[0]].get("error") else ""
    elif not (isinstance(receipts["render"], dict) and receipts["render"].get("status") == "ok"):
        row["status"] = "failed"
        present = [i for i, s in enumerate(STAGES) if isinstance(receipts[s], dict)]
        missing = [s for s in STAGES[present[0]:] if not isinstance(receipts[s], dict)] if present else []
        where = os.path.join(study, "stages")
        if missing:
            row["failed_stage"] = missing[0]
            row["error"] = f"{missing[0]}: no receipt in {where} (the stage did not finish)"
        else:
            row["error"] = f"no stage receipts in {where} (the scan did not run)"
    else:
        row["status"] = "ok"

    manifest = load(os.path.join(study, "manifest.json")) or {}
    reports, total = {}, 0.0
    for entry in manifest.get("stages", []) if isinstance(manifest, dict) else []:
        if not isinstance(entry, dict):
            continue
        name = entry.get("stage")
        reports[name] = entry.get("report") or {}
        t = entry.get("wall_seconds")
        if isinstance(t, (int, float)):
            if f"time_{name}_s" in row:
                row[f"time_{name}_s"] = number(t, 2)
            total += t
    if reports:
        row["time_total_s"] = number(total, 2)
    # Stages whose last `flyover stage` call computed its result (not reused from the cache).
    row["computed_stages"] = " ".join(
        s for s in STAGES if isinstance(receipts[s], dict) and receipts[s].get("status") == "ok" and receipts[s].get("computed"))

    seg = reports.get("segment", {})
    row["lumen_volume_ml"] = number(seg.get("lumen_volume_ml"), 2)
    pieces = seg.get("pieces")
    if isinstance(pieces, list):
        row["lumen_pieces"] = len(pieces)
        row["collapses"] = max(0, len(pieces) - 1)
    elif isinstance(pieces, (int, float)):
        row["lumen_pieces"] = pieces
        row["collapses"] = max(0, int(pieces) - 1)
    contacts = [v for r in reports.values() for v in find_key(r, "contacts")]
    row["contacts"] = count(contacts[0]) if contacts else ""
    tube = [v for r in reports.values() for v in find_key(r, "rectal_tube")]
    row["rectal_tube"] = count(tube[0]) if tube else ""

    cl = reports.get("centerline", {})
    row["centerline_length_mm"] = number(cl.get("length_mm"), 1)
    centerline = load(os.path.join(study, "centerline.json"))
    if isinstance(centerline, dict):
        pos, bridged = centerline.get("position_mm"), centerline.get("bridged")
        if isinstance(pos, list) and len(pos) > 1:
            try:
                seg_len = [math.dist(pos[i], pos[i + 1]) for i in range(len(pos) - 1)]
                if row["centerline_length_mm"] == "":
                    row["centerline_length_mm"] = round(sum(seg_len), 1)
                if isinstance(bridged, list) and len(bridged) == len(pos):
                    row["bridged_mm"] = round(sum(l for i, l in enumerate(seg_len) if bridged[i] and bridged[i + 1]), 1)
            except (TypeError, ValueError):
                pass

    cov = load(os.path.join(study, "coverage", "coverage.json"))
    if isinstance(cov, dict):
        row["coverage_flyover"] = fraction(dig(cov, "flyover", "both_cameras"))
        row["coverage_flyover_with_review"] = fraction(cov.get("flyover_with_review"))
        row["coverage_flythrough_two_way"] = fraction(dig(cov, "flythrough", "two_way"))
        row["missed_regions"] = count(dig(cov, "flyover", "both_cameras", "missed_regions_count"))
    for key in ("polyps", "voids"):
        values = [v for r in list(reports.values()) + [cov or {}] for v in find_key(r, key)]
        row[key] = count(values[0]) if values else ""

    warnings = []
    for name in STAGES + sorted(set(reports) - set(STAGES)):
        for w in find_key(reports.get(name, {}), "warnings"):
            for item in (w if isinstance(w, list) else [w]):
                if item:
                    warnings.append(f"{name}: {item}" if isinstance(item, str) else f"{name}: {json.dumps(item)}")
    row["warnings"] = " | ".join(warnings)

    if os.path.isfile(os.path.join(study, "overview.png")):
        row["overview"] = os.path.join("studies", sid, "overview.png")
    return row


def write_atomically(path, text):
    tmp = f"{path}.tmp-{os.getpid()}"
    with open(tmp, "w", encoding="utf-8", newline="") as f:
        f.write(text)
    os.replace(tmp, path)


def to_csv(rows):
    import io
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r[k] is None else r[k]) for k in COLUMNS})
    return buf.getvalue()


def to_html(rows, html_path, out_dir, csv_path):
    ok = sum(r["status"] == "ok" for r in rows)
    shown = [c for c in COLUMNS if c not in ("overview",)]
    head = "".join(f"<th>{html.escape(c)}</th>" for c in ["overview"] + shown)
    body = []
    rel_base = os.path.relpath(out_dir, os.path.dirname(os.path.abspath(html_path)) or ".")
    for r in rows:
        if r["overview"]:
            src = html.escape(os.path.join(rel_base, r["overview"]) if rel_base != "." else r["overview"])
            thumb = f'<a href="{src}"><img src="{src}" width="160" alt="overview of {html.escape(r["id"])}"></a>'
        else:
            thumb = "no overview"
        cells = "".join(f"<td>{html.escape(str(r[c]))}</td>" for c in shown)
        body.append(f'<tr class="{html.escape(r["status"])}"><td>{thumb}</td>{cells}</tr>')
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>flyover cohort report</title>
<style>
body {{ font-family: sans-serif; margin: 1em; }}
table {{ border-collapse: collapse; font-size: 12px; }}
th, td {{ border: 1px solid #ccc; padding: 3px 5px; vertical-align: top; }}
th {{ background: #eee; position: sticky; top: 0; }}
tr.failed td {{ background: #fde4e4; }}
</style></head><body>
<h1>flyover cohort report</h1>
<p>{len(rows)} scans: {ok} ok, {len(rows) - ok} failed. Coverage is the fraction of the lumen surface seen;
world coordinates are LPS mm. The same table: <a href="{html.escape(os.path.relpath(csv_path, os.path.dirname(os.path.abspath(html_path))))}">{html.escape(os.path.basename(csv_path))}</a>.</p>
<table><thead><tr>{head}</tr></thead><tbody>
{chr(10).join(body)}
</tbody></table></body></html>
"""


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="the cohort folder (holds studies/)")
    ap.add_argument("--csv", required=True)
    ap.add_argument("--html", required=True)
    ap.add_argument("ids", nargs="+")
    a = ap.parse_args(argv)
    rows = [scan_row(a.out, sid) for sid in a.ids]
    write_atomically(a.csv, to_csv(rows))
    write_atomically(a.html, to_html(rows, a.html, a.out, a.csv))
    print(f"cohort report: {len(rows)} scans, {sum(r['status'] == 'ok' for r in rows)} ok -> {a.csv}, {a.html}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
