#!/bin/bash
# Forty-eighth session (README "Work directory, caching and resume", the ray runner). Needs a checkout at /tmp/rayclone
# with .venv installed with the ray extra, and the old / new flows/runtime.py in /work/s48/raytime. Alternate: ray with the old runtime (prefect-ray's own Ray per stage, temporary Prefect servers in the workers),
# ray with the new one, threads; smoke profile --until synthesize, a fresh work dir each; wall time of the command
cd /tmp/rayclone
for rep in 1 2 3; do
  for v in old new threads; do
    if [ $v = threads ]; then cp /work/s48/raytime/runtime_new.py flows/runtime.py; R=threads; else cp /work/s48/raytime/runtime_$v.py flows/runtime.py; R=ray; fi
    W=/tmp/u/rt_${v}_$rep; rm -rf $W
    s=$(date +%s.%N)
    timeout 900 .venv/bin/multigrasp run --profile smoke --runner $R --workdir $W --until synthesize > /work/s48/raytime/${v}_$rep.log 2>&1
    rc=$?
    e=$(date +%s.%N)
    echo "{\"variant\": \"$v\", \"rep\": $rep, \"rc\": $rc, \"wall_s\": $(echo "$e - $s" | bc)}" >> /work/s48/raytime/times.jsonl
  done
done
cp /work/s48/raytime/runtime_new.py flows/runtime.py
echo ALLDONE >> /work/s48/raytime/times.jsonl
