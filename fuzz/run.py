"""Coverage-guided fuzzing of the untrusted-bytes parsers with atheris (libFuzzer).

    .venv/bin/python fuzz/run.py TARGET [--seconds 60] [-- libFuzzer flags]
    .venv/bin/python fuzz/run.py TARGET --replay [--asan]

TARGET: ``mcap``, ``json``, ``nmea``, ``asterix`` (:mod:`fuzz.targets`), or ``all``
(each in turn, ``--seconds`` each). ``make fuzz`` runs ``all`` with ``FUZZ_SECONDS``
(default 300) per target, then replays every corpus under the sanitizers.

Two phases, because the two tools do not mix here: with gcc's AddressSanitizer
runtime preloaded (Python itself is not built with it), atheris loses its coverage
counters ("Coverage symbols are being provided by a library other than libFuzzer") and
the search goes blind. So (1) the coverage-guided search runs with the installed
extensions: atheris instruments the Python of ``pipeline`` (reader, decoders,
importers); the compiled extensions (``_json_columns``, ``_mcap_records``) run but are
not coverage-instrumented (no clang/libFuzzer build here); (2) ``--replay --asan`` runs
every corpus input and seed once more through the same target with the
AddressSanitizer + UndefinedBehaviorSanitizer builds of the extensions (``make
fuzz-asan``, ``build/asan``, loaded in place of the installed ones), so a memory error
or undefined behaviour in C aborts the replay with a report.

Seeds: ``fuzz/seeds/<target>/`` (written on first run from
:mod:`pipeline.simulate.hostile` and the real samples when present); the corpus
grows in ``fuzz/corpus/<target>/`` (not committed); a crashing input is written to
``fuzz/crashes/<target>-crash-<sha1>``: copy it to ``tests/fuzz/regressions/<target>/``
and fix the cause (``tests/fuzz/test_regressions.py`` replays every file there).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(REPO))


def _seeds(target: str) -> Path:
    d = HERE / "seeds" / target
    if d.exists() and any(d.iterdir()):
        return d
    d.mkdir(parents=True, exist_ok=True)
    from pipeline.simulate import hostile as h

    if target == "mcap":
        msgs = [(h.T0_NS + i * 10**9, h.radar_report(i)) for i in range(20)]
        h.write_radar_mcap(d / "radar.mcap", msgs)
    elif target == "json":
        h.write(d / "radar.jsonl", b"\n".join(h.radar_report(i) for i in range(8)))
    elif target == "nmea":
        h.write(d / "gnss.log", "\r\n".join(h.nmea_fixes(5)) + "\r\n")
        h.write(d / "ais.nmea", "!AIVDM,1,1,,A,13RlIW?04F1beOVEFLB9bRvH0L0L,0*6C\n"
                "!AIVDM,2,1,1,A,55?MbV02;H;s<HtKR20EHE:0@T4@Dn2222222216L961O5Gf0NSQEp6ClRp8,0*1C\n"
                "!AIVDM,2,2,1,A,88888888880,2*25\n")  # fmt: skip
    elif target == "asterix":
        blocks = h.cat010_blocks(12)
        h.write(d / "raw.ast", b"".join(blocks))
        frames = [(h.T0_NS + i * 10**8, h.udp_frame(b)) for i, b in enumerate(blocks)]
        h.write(d / "cap.pcap", h.pcap_bytes(frames)[0])
        h.write(d / "cap.pcapng", h.pcapng_bytes(frames)[0])
    real = REPO.parent.parent / "shared" / "data" / "real" / "asterix"
    if target == "asterix" and real.is_dir():  # a copy in the seed folder is not committed
        for p in sorted(real.glob("*"))[:6]:
            if p.is_file() and p.stat().st_size < 65_536:
                (d / f"real_{p.name}").write_bytes(p.read_bytes())
    return d


def _use_asan_builds() -> None:
    """Load the sanitizer builds of the extensions in place of the installed ones."""
    import pipeline.decode
    import pipeline.io

    for pkg in (pipeline.decode, pipeline.io):
        sub = REPO / "build" / "asan" / Path(*pkg.__name__.split("."))
        if not any(sub.glob("*.so")):
            raise SystemExit(f"no sanitizer build in {sub}: run `make fuzz-asan`")
        pkg.__path__.insert(0, str(sub))


def replay(target: str, asan: bool) -> int:
    """Every seed and corpus input once through ``target``; the count, or an exception."""
    if asan:
        _use_asan_builds()
    from fuzz import targets

    fn = targets.TARGETS[target]
    files = sorted(p for d in (_seeds(target), HERE / "corpus" / target) if d.is_dir()
                   for p in d.iterdir() if p.is_file())  # fmt: skip
    for p in files:
        fn(p.read_bytes())
    if asan:
        from pipeline.decode import _json_columns
        from pipeline.io import _mcap_records

        assert "build/asan" in _json_columns.__file__ and "build/asan" in _mcap_records.__file__
    print(f"replay {target}: {len(files)} inputs, no finding"
          + (" (ASan+UBSan builds of the C extensions)" if asan else ""), flush=True)
    return 0


def fuzz_one(target: str, seconds: int, asan: bool, extra: list[str]) -> int:
    import atheris

    if asan:
        _use_asan_builds()
    with atheris.instrument_imports(include=["pipeline"]):
        import importlib

        for mod in ("pipeline.convert.legacy", "pipeline.decode.registry",
                    "pipeline.io.mcap_read"):  # fmt: skip
            importlib.import_module(mod)
        from fuzz import targets
    fn = targets.TARGETS[target]
    corpus = HERE / "corpus" / target
    corpus.mkdir(parents=True, exist_ok=True)
    crashes = HERE / "crashes"
    crashes.mkdir(exist_ok=True)
    args = [sys.argv[0], str(corpus), str(_seeds(target)), f"-max_total_time={seconds}",
            f"-artifact_prefix={crashes}/{target}-", "-max_len=65536", "-timeout=30",
            "-rss_limit_mb=4096", "-print_final_stats=1", *extra]  # fmt: skip
    atheris.Setup(args, fn)
    atheris.Fuzz()
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("target", choices=["mcap", "json", "nmea", "asterix", "all"])
    ap.add_argument("--seconds", type=int, default=60)
    ap.add_argument("--asan", action="store_true")
    ap.add_argument("--replay", action="store_true", help="run the corpus once, no search")
    ap.add_argument("extra", nargs="*")
    a = ap.parse_args()
    if a.target != "all":
        if a.replay:
            return replay(a.target, a.asan)
        return fuzz_one(a.target, a.seconds, a.asan, a.extra)
    worst = 0
    for t in ("mcap", "json", "nmea", "asterix"):  # one process each: libFuzzer exits
        cmd = [sys.executable, __file__, t, "--seconds", str(a.seconds)]
        cmd += ["--asan"] if a.asan else []
        cmd += ["--replay"] if a.replay else []
        print(f"== fuzz {t}: " + ("replay" if a.replay else f"{a.seconds} s"), flush=True)
        worst = max(worst, subprocess.run(cmd, env=os.environ, check=False).returncode)
    return worst


if __name__ == "__main__":
    sys.exit(main())
