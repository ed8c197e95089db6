#!/usr/bin/env python3
"""Widens a copy of a dataset folder to at least N images, for measurements at scale
(tools/bench-finish, tools/bench-report): its images, listed in its shard manifests, are
repeated until there are N or more. Image i of the widened folder takes the files of the
folder's image (i mod n) in index order: its folder hard links to that image's files and
its manifest line is that image's, renumbered (index, id, and the paths under
images/<id>/); its instance, split and labels stay the copied image's. The shard
manifests are replaced by one, shard-0-of-1.jsonl; manifest.jsonl and coco/ are removed
(they no longer match). Files are replaced, never written in place, so DATA may be a
hard-linked copy (cp -rl) of the folder.

With --job the folder must be finished (every image of its job listed once: indices
0 .. n-1) and its job.toml's defective / defect_free counts are multiplied, so that the
widened job lists exactly the widened images (what the finish step checks); without it
any set of images is widened (what the realism report reads).

Usage: tools/widen-dataset.py DATA N [--job]"""
import glob, json, os, re, shutil, sys

args = [a for a in sys.argv[1:] if a != "--job"]
job_counts = "--job" in sys.argv[1:]
if len(args) != 2 or not re.fullmatch(r"[1-9][0-9]*", args[1]):
    sys.exit(__doc__.strip().splitlines()[-1])
data, want = args[0], int(args[1])
entries = []
for m in sorted(glob.glob(os.path.join(data, "manifests", "*.jsonl"))):
    entries += [json.loads(line) for line in open(m) if line.strip()]
    os.remove(m)
entries.sort(key=lambda e: e["index"])
n = len(entries)
if n == 0:
    sys.exit("widen-dataset: %s lists no image in manifests/*.jsonl" % data)
f = -(-want // n)
if job_counts:
    if [e["index"] for e in entries] != list(range(n)):
        sys.exit("widen-dataset: --job needs a finished dataset (every image listed once)")
    job_path = os.path.join(data, "job.toml")
    job = open(job_path).read()
    job, k = re.subn(r"^(defective|defect_free)(\s*=\s*)(\d+)",
                     lambda m: "%s%s%d" % (m[1], m[2], int(m[3]) * f), job, flags=re.M)
    if k == 0:
        sys.exit("widen-dataset: the job has no defective / defect_free counts to widen")
    # A new file, not the old one rewritten: the folder may be a hard-linked copy.
    open(job_path + ".tmp", "w").write(job)
    os.replace(job_path + ".tmp", job_path)
for stale in ["manifest.jsonl"]:
    if os.path.exists(os.path.join(data, stale)):
        os.remove(os.path.join(data, stale))
shutil.rmtree(os.path.join(data, "coco"), ignore_errors=True)


def renamed(v, old, new):
    if isinstance(v, str):
        return v.replace("images/%s/" % old, "images/%s/" % new)
    if isinstance(v, list):
        return [renamed(x, old, new) for x in v]
    if isinstance(v, dict):
        return {k: renamed(x, old, new) for k, x in v.items()}
    return v


# Every source folder is moved aside first, so that a number the widening gives never
# meets an image folder of the source.
aside = {}
for e in entries:
    if e["id"] not in aside:
        aside[e["id"]] = os.path.join(data, "images", ".widen-" + e["id"])
        os.rename(os.path.join(data, "images", e["id"]), aside[e["id"]])
with open(os.path.join(data, "manifests", "shard-0-of-1.jsonl"), "w") as out:
    for i in range(n * f):
        src = entries[i % n]
        new_id = "%06d" % i
        e = renamed(src, src["id"], new_id)
        e["index"], e["id"] = i, new_id
        ddir = os.path.join(data, "images", new_id)
        os.mkdir(ddir)
        for name in os.listdir(aside[src["id"]]):
            os.link(os.path.join(aside[src["id"]], name), os.path.join(ddir, name))
        out.write(json.dumps(e, separators=(",", ":")) + "\n")
for d in aside.values():
    shutil.rmtree(d)
print("widened to %d images (%d x %d)" % (n * f, n, f))
