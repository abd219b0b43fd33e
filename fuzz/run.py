"""Coverage-guided fuzzing of the untrusted-bytes parsers with atheris (libFuzzer).

    .venv/bin/python fuzz/run.py TARGET [--seconds 60] [--asan] [-- libFuzzer flags]

TARGET: ``mcap``, ``json``, ``nmea``, ``asterix`` (:mod:`fuzz.targets`), or ``all``
(each in turn, ``--seconds`` each). ``make fuzz`` runs ``all`` with
``FUZZ_SECONDS`` (default 300) per target.

Coverage: atheris instruments the Python of ``pipeline`` (the reader, decoders,
importers); the compiled extensions (``_json_columns``, ``_mcap_records``) are not
coverage-instrumented (gcc, no libFuzzer counters), but with ``--asan`` they are the
AddressSanitizer + UndefinedBehaviorSanitizer builds from ``make fuzz-asan`` (in
``build/asan``, loaded in place of the installed ones), so a memory error in them
aborts the run with a report. Seeds: ``fuzz/seeds/<target>/`` (written on first run
from :mod:`pipeline.simulate.hostile` and the real samples when present); the corpus
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


def fuzz_one(target: str, seconds: int, asan: bool, extra: list[str]) -> int:
    import atheris

    if asan:  # the sanitizer builds of the extensions, in place of the installed ones
        import pipeline.decode
        import pipeline.io

        for pkg in (pipeline.decode, pipeline.io):
            sub = REPO / "build" / "asan" / Path(*pkg.__name__.split("."))
            pkg.__path__.insert(0, str(sub))
    with atheris.instrument_imports(include=["pipeline"]):
        from fuzz import targets

        import pipeline.convert.legacy  # noqa: F401
        import pipeline.decode.registry  # noqa: F401
        import pipeline.io.mcap_read  # noqa: F401
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
    ap.add_argument("extra", nargs="*")
    a = ap.parse_args()
    if a.target != "all":
        return fuzz_one(a.target, a.seconds, a.asan, a.extra)
    worst = 0
    for t in ("mcap", "json", "nmea", "asterix"):  # one process each: libFuzzer exits
        cmd = [sys.executable, __file__, t, "--seconds", str(a.seconds)]
        cmd += ["--asan"] if a.asan else []
        print(f"== fuzz {t}: {a.seconds} s", flush=True)
        worst = max(worst, subprocess.run(cmd, env=os.environ, check=False).returncode)
    return worst


if __name__ == "__main__":
    sys.exit(main())
