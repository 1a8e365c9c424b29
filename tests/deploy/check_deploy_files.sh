#!/usr/bin/env bash
# The deployment files as their own tools read them (ctest `deploy.files`,
# every preset): docker/compose.yaml with and without the `scale` profile
# through `docker-compose config` (Debian's 1.29, installed by
# docker/install-deps.sh), and docker/k8s through `kubectl kustomize` where a
# kubectl is installed. No engine or cluster is needed or used. Exits 77
# (skipped) when neither tool is present.
set -euo pipefail
cd "$(dirname "$0")/../.."
checked=0
if command -v docker-compose >/dev/null 2>&1; then
  for profile in "" scale; do
    args=(-f docker/compose.yaml)
    [ -n "$profile" ] && args+=(--profile "$profile")
    out=$(docker-compose "${args[@]}" config) || {
      echo "docker-compose ${args[*]} config refused docker/compose.yaml" >&2; exit 1; }
    services=$(docker-compose "${args[@]}" config --services | sort | tr '\n' ' ')
    echo "compose${profile:+ --profile $profile}: $services"
    for s in server device observer; do
      [[ " $services" == *" $s "* ]] || { echo "compose: service '$s' missing" >&2; exit 1; }
    done
    if [ "$profile" = scale ]; then
      for s in hapticpd-1 hapticpd-2 hapticpd-3 balancer; do
        [[ " $services" == *" $s "* ]] || { echo "compose --profile scale: service '$s' missing" >&2; exit 1; }
      done
    fi
    [ -n "$out" ]
  done
  checked=$((checked + 1))
else
  echo "docker-compose not installed: docker/compose.yaml not checked"
fi
if command -v kubectl >/dev/null 2>&1; then
  manifests=$(kubectl kustomize --load-restrictor LoadRestrictionsNone docker/k8s) || {
    echo "kubectl kustomize refused docker/k8s" >&2; exit 1; }
  kinds=$(grep '^kind:' <<<"$manifests" | sort | uniq -c | tr -s ' ' | tr '\n' ';')
  echo "k8s: $kinds"
  for k in StatefulSet ConfigMap Namespace; do
    grep -q "^kind: $k\$" <<<"$manifests" || { echo "k8s: no $k" >&2; exit 1; }
  done
  checked=$((checked + 1))
else
  echo "kubectl not installed: docker/k8s not checked"
fi
[ "$checked" -gt 0 ] || exit 77
