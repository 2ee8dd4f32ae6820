"""Merge the two labelling passes of the banner's structures into structures_labelled.json.

Inputs (the scratch folder of the labelling, see README.md here): the proposals of
propose_structures.py, pass 1 and pass 2 (``{proposal_id: kind}`` each, made independently from
the same sheets by the written protocol), and the resolution of every disagreement
(``{proposal_id: kind}``, decided by looking at the crop again). Output: per tile, per structure
``{id, index, u, v, u_peak, v_peak, area_px, bbox, kind, pass1, pass2, resolved_by}`` (and
``note``, ``{pass1|pass2|review: text}``, where a labeller wrote one) and a header with
the protocol version, the counts, the confusion table of the two passes and their agreement (raw
fraction and Cohen's kappa). With ``--readme`` the counts block between the markers
``<!-- structures-counts:begin -->`` and ``<!-- structures-counts:end -->`` of README.md is
rewritten from the output file.

Usage:
  python resolve_labels.py PROPOSALS.json PASS1.json PASS2.json|- RESOLUTION.json|- OUT.json \
      [PASS1_NOTES.json [PASS2_NOTES.json|- [RESOLUTION_NOTES.json]]]
  python resolve_labels.py --readme OUT.json README.md

(``-`` for pass 2 and the resolution when pass 2 never arrived: then kind = pass 1.)
"""
import json
import sys
from collections import Counter

KINDS = ["isolated", "cluster", "streak", "instrument", "overlay", "border", "texture"]
PROTOCOL = "1"


def cohen_kappa(a, b):
    n = len(a)
    po = sum(x == y for x, y in zip(a, b)) / n
    ca, cb = Counter(a), Counter(b)
    pe = sum(ca[k] * cb[k] for k in set(ca) | set(cb)) / (n * n)
    return po, (po - pe) / (1 - pe) if pe < 1 else 1.0


def merge(proposals, pass1, pass2, resolution, *notes):
    tiles_in = json.load(open(proposals))["tiles"]
    notes = [json.load(open(n)) if n != "-" else {} for n in notes] + [{}, {}, {}]
    p1 = json.load(open(pass1))
    p2 = json.load(open(pass2)) if pass2 != "-" else None
    res = json.load(open(resolution)) if resolution != "-" else {}
    ids = [s["id"] for t in tiles_in.values() for s in t]
    assert set(p1) == set(ids), "pass 1 does not label every proposal"
    assert all(k in KINDS for k in p1.values())
    if p2 is not None:
        assert set(p2) == set(ids), "pass 2 does not label every proposal"
        assert all(k in KINDS for k in p2.values())
        dis = {i for i in ids if p1[i] != p2[i]}
        assert set(res) == dis, "the resolution must cover exactly the disagreements"
        assert all(k in KINDS for k in res.values())
    tiles = {}
    for tid, props in tiles_in.items():
        out = []
        for s in props:
            i = s["id"]
            a = p1[i]
            b = p2[i] if p2 is not None else None
            if b is None:
                kind, by = a, "pass1_only"
            elif a == b:
                kind, by = a, "agreement"
            else:
                kind, by = res[i], "review"
            out.append({"id": i, "index": s["index"], "u": s["u"], "v": s["v"],
                        "u_peak": s["u_peak"], "v_peak": s["v_peak"], "area_px": s["area_px"],
                        "bbox": s["bbox"], "kind": kind, "pass1": a, "pass2": b,
                        "resolved_by": by})
            note = {k: n[i] for k, n in zip(("pass1", "pass2", "review"), notes) if i in n}
            if note:
                out[-1]["note"] = note
        tiles[tid] = out
    allk = [s["kind"] for t in tiles.values() for s in t]
    header = {
        "labelmap": "labels/structures_labelmap.png",
        "source": "tests/data/real/hyperkvasir_banner.jpg (Hyper-Kvasir banner, CC BY 4.0, "
                  "Borgli et al. 2020): 24 frames as 280 x 280 tiles, tile id r{row}c{col} at "
                  "x = col*280, y = row*280",
        "coordinates": "tile pixels, u = column, v = row, pixel centres at integer coordinates; "
                       "(u, v) the structure's centroid, (u_peak, v_peak) its peak, bbox "
                       "[u0, v0, width, height]; the structure's pixels are those of "
                       "labels/structures_labelmap.png (banner-sized, uint16) equal to its index",
        "protocol_version": PROTOCOL,
        "protocol": "tests/data/real/README.md, section 'Every bright structure of the banner'",
        "proposals": "tests/data/real/propose_structures.py",
        "kinds": KINDS,
        "frames": len(tiles),
        "structures": len(allk),
        "counts": {k: allk.count(k) for k in KINDS},
        "counts_per_tile": {t: {k: sum(s["kind"] == k for s in v) for k in KINDS}
                            for t, v in tiles.items()},
    }
    if p2 is not None:
        a = [p1[i] for i in ids]
        b = [p2[i] for i in ids]
        po, kappa = cohen_kappa(a, b)
        conf = {k: {l: sum(x == k and y == l for x, y in zip(a, b)) for l in KINDS}
                for k in KINDS}
        per_kind = {}
        for k in KINDS:
            n1, n2 = a.count(k), b.count(k)
            both = conf[k][k]
            per_kind[k] = {"pass1": n1, "pass2": n2, "both": both,
                           "agreement_of_either": round(both / max(n1 + n2 - both, 1), 3)}
        # agreement on the target alone: isolated vs anything else
        ia = [x == "isolated" for x in a]
        ib = [y == "isolated" for y in b]
        po_i, kappa_i = cohen_kappa(ia, ib)
        header["agreement"] = {
            "raw": round(po, 4), "cohen_kappa": round(kappa, 4),
            "agreements": sum(x == y for x, y in zip(a, b)),
            "disagreements": sum(x != y for x, y in zip(a, b)),
            "isolated_vs_rest": {"raw": round(po_i, 4), "cohen_kappa": round(kappa_i, 4)},
            "per_kind": per_kind,
            "confusion_pass1_rows_pass2_columns": conf,
        }
        iso = [s for t in tiles.values() for s in t if s["kind"] == "isolated"]
        header["isolated_by"] = {"agreement": sum(s["resolved_by"] == "agreement" for s in iso),
                                 "review": sum(s["resolved_by"] == "review" for s in iso)}
        header["resolution"] = {
            "resolved_by_review": sum(s["resolved_by"] == "review" for t in tiles.values()
                                      for s in t),
            "review_kept_pass1": sum(s["resolved_by"] == "review" and s["kind"] == s["pass1"]
                                     for t in tiles.values() for s in t),
            "review_took_pass2": sum(s["resolved_by"] == "review" and s["kind"] == s["pass2"]
                                     for t in tiles.values() for s in t),
            "review_other": sum(s["resolved_by"] == "review" and s["kind"] not in
                                (s["pass1"], s["pass2"]) for t in tiles.values() for s in t),
        }
    else:
        header["agreement"] = None
        header["note"] = "pass 2 never arrived: the kinds are pass 1 alone, not checked"
    return {"header": header, "tiles": tiles}


def readme_block(out):
    h = out["header"]
    L = ["<!-- structures-counts:begin -->",
         "(Written by `resolve_labels.py --readme` from `structures_labelled.json`.)", "",
         f"{h['structures']} structures on {h['frames']} frames (protocol version "
         f"{h['protocol_version']}):", "",
         "| kind | " + " | ".join(h["kinds"]) + " | all |",
         "|---|" + "---|" * (len(h["kinds"]) + 1),
         "| structures | " + " | ".join(str(h["counts"][k]) for k in h["kinds"])
         + f" | {h['structures']} |", ""]
    nt = sum(1 for t in h["counts_per_tile"].values() if t["isolated"] > 0)
    L.append(f"`isolated` highlights (the detector's targets): {h['counts']['isolated']}, on "
             f"{nt} of the {h['frames']} frames.")
    if h.get("agreement"):
        ia = h["isolated_by"]
        L.append(f"Of them {ia['agreement']} were called `isolated` by both passes and "
                 f"{ia['review']} were decided in review.")
    a = h.get("agreement")
    if a:
        L += ["",
              f"Agreement of the two independent passes: {a['agreements']} of "
              f"{a['agreements'] + a['disagreements']} ({a['raw']:.3f}), Cohen's kappa "
              f"{a['cohen_kappa']:.3f}; on `isolated` against the rest: {a['isolated_vs_rest']['raw']:.3f}, "
              f"kappa {a['isolated_vs_rest']['cohen_kappa']:.3f}. Per kind (labelled so by pass 1, "
              "by pass 2, by both):", "",
              "| kind | pass 1 | pass 2 | both |", "|---|---|---|---|"]
        for k in h["kinds"]:
            p = a["per_kind"][k]
            L.append(f"| {k} | {p['pass1']} | {p['pass2']} | {p['both']} |")
        L += ["", "Confusion (rows pass 1, columns pass 2):", "",
              "| pass 1 \\ pass 2 | " + " | ".join(h["kinds"]) + " |",
              "|---|" + "---|" * len(h["kinds"])]
        for k in h["kinds"]:
            row = a["confusion_pass1_rows_pass2_columns"][k]
            L.append(f"| {k} | " + " | ".join(str(row[l]) for l in h["kinds"]) + " |")
        r = h["resolution"]
        L += ["", f"The {r['resolved_by_review']} disagreements were decided by looking at the "
              f"crop again: pass 1's kind kept {r['review_kept_pass1']} times, pass 2's taken "
              f"{r['review_took_pass2']} times, a third kind {r['review_other']} times."]
    else:
        L += ["", "No second pass: the kinds are one labeller's, unchecked."]
    L.append("<!-- structures-counts:end -->")
    return "\n".join(L)


if __name__ == "__main__":
    if sys.argv[1] == "--readme":
        out = json.load(open(sys.argv[2]))
        text = open(sys.argv[3]).read()
        b = text.index("<!-- structures-counts:begin -->")
        e = text.index("<!-- structures-counts:end -->") + len("<!-- structures-counts:end -->")
        open(sys.argv[3], "w").write(text[:b] + readme_block(out) + text[e:])
    else:
        out = merge(*sys.argv[1:5], *sys.argv[6:])
        with open(sys.argv[5], "w") as f:   # the header indented, one structure a line
            f.write('{"header": ' + json.dumps(out["header"], indent=1) + ',\n "tiles": {')
            for k, (tid, structs) in enumerate(out["tiles"].items()):
                f.write((",\n" if k else "\n") + f'  "{tid}": [\n')
                f.write(",\n".join("   " + json.dumps(x) for x in structs) + "\n  ]")
            f.write("\n }\n}\n")
        h = out["header"]
        print(h["structures"], h["counts"], h.get("agreement") and
              {k: h["agreement"][k] for k in ("raw", "cohen_kappa", "disagreements")})
