#!/usr/bin/env python3
"""A load on `matlaber serve` for tests/cli_serve.sh (python3's standard library only).

CLIENTS threads at once, each sending REQUESTS requests, each on a connection of its own: the job
list, one job, the events of a running job (followed for a moment, then again from its last id, as a
reconnecting EventSource does) and the whole events of a finished job; with --submit, COUNT jobs
posted at the same time by threads of their own. Every answer must be 2xx and of the right kind:
the list names no job twice and runs no more than max_running; an event stream is made of
"id: N\\ndata: JSON" events, N the byte offset after the line (so N grows by the line's length + 1)
and ": keepalive" comments; the finished job's events are the same bytes at every read. Prints a
summary line, then each problem (at most 20), and exits 1 when there was one. --ids FILE gets the
submitted jobs' ids, one a line.
"""
import argparse
import http.client
import json
import random
import socket
import sys
import threading
import time
import urllib.parse

p = argparse.ArgumentParser()
p.add_argument("url")
p.add_argument("--token", default="")
p.add_argument("--clients", type=int, default=200)
p.add_argument("--requests", type=int, default=5, help="per client")
p.add_argument("--finished", required=True, help="a finished job's id")
p.add_argument("--running", required=True, help="running jobs' ids, comma-separated")
p.add_argument("--follow", type=float, default=1.0, help="seconds a running job's events are followed")
p.add_argument("--submit", help="a file holding the body of the jobs to post")
p.add_argument("--count", type=int, default=0, help="how many jobs to post")
p.add_argument("--ids", help="where the posted jobs' ids go")
a = p.parse_args()
u = urllib.parse.urlsplit(a.url)
HEADERS = {"Authorization": "Bearer " + a.token} if a.token else {}
RUNNING = a.running.split(",")

lock = threading.Lock()
problems, codes, submitted = [], {}, []
counts = {"requests": 0, "streams": 0, "events": 0, "replays": 0, "resumed": 0}


def problem(msg):
    with lock:
        problems.append(msg)


def count(key, n=1):
    with lock:
        counts[key] += n


def connect(timeout=60):
    return http.client.HTTPConnection(u.hostname, u.port, timeout=timeout)


def get(path):
    """One request on a connection of its own: (status, body) or (None, None) after a problem."""
    c = connect()
    try:
        c.request("GET", path, headers=HEADERS)
        r = c.getresponse()
        body = r.read()
        with lock:
            codes[r.status] = codes.get(r.status, 0) + 1
            counts["requests"] += 1
        if not 200 <= r.status < 300:
            problem(f"GET {path}: HTTP {r.status} {body[:200]!r}")
            return None, None
        return r.status, body
    except (OSError, http.client.HTTPException) as e:
        problem(f"GET {path}: {e!r}")
        return None, None
    finally:
        c.close()


def parse_events(text, start, path):
    """The complete events of a stream's text from byte offset start: [(id, data)], checked."""
    out, at = [], start
    for block in text.split("\n\n")[:-1]:   # (what follows the last blank line is not complete yet)
        if block.startswith(":"):
            if block != ": keepalive":
                problem(f"{path}: a comment that is not the keepalive: {block!r}")
            continue
        lines = block.split("\n")
        if len(lines) != 2 or not lines[0].startswith("id: ") or not lines[1].startswith("data: "):
            problem(f"{path}: a malformed event: {block[:200]!r}")
            return out
        data = lines[1][6:]
        at += len(data.encode()) + 1
        if lines[0][4:] != str(at):
            problem(f"{path}: event id {lines[0][4:]}, expected {at} (the offset after the line)")
            return out
        try:
            if "event" not in json.loads(data):
                raise ValueError("no 'event'")
        except ValueError as e:
            problem(f"{path}: data is not an event ({e}): {data[:200]!r}")
            return out
        out.append((at, data))
    return out


def stream(path, last=0, follow=None):
    """The events of path from offset last: to the stream's end (follow None) or for follow seconds."""
    c = connect()
    chunks, ended = [], False
    try:
        c.request("GET", path, headers={**HEADERS, **({"Last-Event-ID": str(last)} if last else {})})
        sock = c.sock   # (the connection lets go of it once the answer says it will close)
        r = c.getresponse()
        with lock:
            codes[r.status] = codes.get(r.status, 0) + 1
            counts["requests"] += 1
        if r.status != 200 or not r.getheader("Content-Type", "").startswith("text/event-stream"):
            problem(f"GET {path}: HTTP {r.status}, {r.getheader('Content-Type')} {r.read()[:200]!r}")
            return None, False
        end = time.monotonic() + (follow if follow is not None else 60)
        while True:
            left = end - time.monotonic()
            if left <= 0:
                if follow is None:
                    problem(f"GET {path}: no end after 60 s")
                break
            sock.settimeout(left)
            try:
                b = r.read1(65536)
            except socket.timeout:
                break
            if not b:
                ended = True
                break
            chunks.append(b)
    except (OSError, http.client.HTTPException) as e:
        problem(f"GET {path}: {e!r}")
        return None, False
    finally:
        c.close()
    return b"".join(chunks).decode("utf-8", "replace"), ended


def follow_running(job):
    """A running job's events for a moment, then again from the last id seen (an EventSource's
    reconnection): both well-formed, the second carrying on at the first's offset."""
    path = f"/api/jobs/{job}/events"
    text, _ = stream(path, follow=a.follow)
    if text is None:
        return
    ev = parse_events(text, 0, path)
    count("streams")
    count("events", len(ev))
    if not ev:
        problem(f"{path}: no event in {a.follow} s of a running job")
        return
    last = ev[-1][0]
    text, _ = stream(path, last=last, follow=0.3)
    if text is not None:
        count("events", len(parse_events(text, last, path + " (Last-Event-ID)")))
        count("resumed")


def submit(body):
    c = connect(timeout=120)
    try:
        c.request("POST", "/api/jobs", body=body, headers={**HEADERS, "Content-Type": "application/json"})
        r = c.getresponse()
        text = r.read()
        with lock:
            codes[r.status] = codes.get(r.status, 0) + 1
            counts["requests"] += 1
        if r.status != 201:
            problem(f"POST /api/jobs: HTTP {r.status} {text[:200]!r}")
            return
        job = json.loads(text)
        if job.get("state") != "queued":
            problem(f"POST /api/jobs: a new job is {job.get('state')!r}, not queued")
        with lock:
            submitted.append(job["id"])
    except (OSError, http.client.HTTPException, ValueError, KeyError) as e:
        problem(f"POST /api/jobs: {e!r}")
    finally:
        c.close()


# the finished job's events, read once alone: every read under the load must give the same bytes
FIN = f"/api/jobs/{a.finished}/events"
reference, ended = stream(FIN)
ref_events = parse_events(reference or "", 0, FIN)
if not ended or not ref_events or '"event":"job"' not in ref_events[-1][1]:
    print(f"the finished job's events ({FIN}) do not end with the job's event: {(reference or '')[-300:]!r}")
    sys.exit(1)


def client(i):
    rng = random.Random(i)
    for k in range(a.requests):
        try:
            one(rng, (i + k) % 5)
        except Exception as e:   # (an answer that is not the JSON it should be)
            problem(f"client {i}: {e!r}")


def one(rng, kind):
    if kind == 0:
        _, body = get("/api/jobs")
        if body is None:
            return
        d = json.loads(body)
        ids = [j["id"] for j in d["jobs"]]
        if len(ids) != len(set(ids)):
            problem(f"GET /api/jobs lists a job twice: {sorted(x for x in ids if ids.count(x) > 1)}")
        running = sum(j["state"] == "running" for j in d["jobs"])
        if running > d["max_running"] or d["running"] > d["max_running"]:
            problem(f"GET /api/jobs: {running} jobs running, max_running {d['max_running']}")
    elif kind == 1:   # one job: a running one, or one of those just submitted
        with lock:
            pick = rng.choice(submitted) if submitted and rng.random() < 0.5 else rng.choice(RUNNING)
        _, body = get(f"/api/jobs/{pick}")
        if body is not None and json.loads(body).get("id") != pick:
            problem(f"GET /api/jobs/{pick}: another job's answer")
    elif kind == 2:
        follow_running(rng.choice(RUNNING))
    elif kind == 3:
        text, ended = stream(FIN)
        count("replays")
        if text is not None and (text != reference or not ended):
            problem(f"{FIN}: {len(text)} bytes (ended: {ended}), not the {len(reference)} of the first read")
    else:
        _, body = get(f"/api/jobs/{a.finished}")
        if body is not None and json.loads(body).get("state") != "done":
            problem(f"GET /api/jobs/{a.finished}: not done")


t0 = time.monotonic()
threads = [threading.Thread(target=client, args=(i,)) for i in range(a.clients)]
if a.submit:
    body = open(a.submit, "rb").read()
    threads += [threading.Thread(target=submit, args=(body,)) for _ in range(a.count)]
for t in threads:
    t.start()
for t in threads:
    t.join()
if len(submitted) != len(set(submitted)):
    problem(f"a job id given twice: {sorted(submitted)}")
if a.ids:
    with open(a.ids, "w") as f:
        f.writelines(s + "\n" for s in submitted)
print(f"{a.clients} clients, {counts['requests']} requests in {time.monotonic() - t0:.1f} s "
      f"(HTTP {', '.join(f'{k}: {v}' for k, v in sorted(codes.items()))}); "
      f"{counts['streams']} running jobs' event streams followed and {counts['resumed']} resumed "
      f"({counts['events']} events), {counts['replays']} replays of a finished job's "
      f"{len(ref_events)} events; {len(submitted)} of {a.count} jobs submitted; {len(problems)} problems")
for m in problems[:20]:
    print("  " + m)
sys.exit(1 if problems else 0)
