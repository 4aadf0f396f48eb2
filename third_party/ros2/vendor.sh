#!/usr/bin/env bash
# Refresh the vendored ROS 2 Jazzy command line (ros2cli), launch and launch_ros from git clones of their repos.
#   third_party/ros2/vendor.sh DIR   where DIR holds clones named launch, launch_ros, rcl_interfaces, ros2cli and
#                                    rosidl_runtime_py (each with a jazzy branch)
# Only the packages the project's users and tests run are kept, without their tests; SOURCES.md records the commits.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
clones="${1:?usage: vendor.sh DIR-with-clones}"
branch="${BRANCH:-jazzy}"
declare -A packages=(
    [launch]="launch launch_xml launch_yaml"
    [launch_ros]="launch_ros ros2launch"
    [rcl_interfaces]="composition_interfaces"
    [ros2cli]="ros2cli ros2interface ros2lifecycle ros2node ros2param ros2pkg ros2run ros2service ros2topic"
    [rosidl_runtime_py]="."
)
{
    echo "# Vendored sources"
    echo
    echo "Written by \`third_party/ros2/vendor.sh\`; do not edit by hand. Apache-2.0, see each repository's LICENSE."
    echo
    echo "| repository | branch | commit | packages |"
    echo "|---|---|---|---|"
} > "$here/SOURCES.md.new"
for repo in launch launch_ros rcl_interfaces ros2cli rosidl_runtime_py; do
    git -C "$clones/$repo" rev-parse --verify "$branch" >/dev/null
    commit="$(git -C "$clones/$repo" rev-parse "$branch")"
    rm -rf "${here:?}/$repo"
    mkdir -p "$here/$repo"
    git -C "$clones/$repo" show "$branch:LICENSE" > "$here/$repo/LICENSE"
    for package in ${packages[$repo]}; do
        git -C "$clones/$repo" archive "$branch" "$package" | tar -x -C "$here/$repo"
    done
    find "$here/$repo" \( -name test -o -name tests -o -name doc -o -name examples -o -name .github \) -type d -prune -exec rm -rf {} +
    find "$here/$repo" \( -name 'CHANGELOG.rst' -o -name 'CONTRIBUTING.md' -o -name 'CODEOWNERS' -o -name 'pytest.ini' -o -name conftest.py \
        -o -name '*.md' ! -name LICENSE \) -type f -delete
    echo "| ros2/$repo | $branch | $commit | ${packages[$repo]/./$repo} |" >> "$here/SOURCES.md.new"
done
mv "$here/SOURCES.md.new" "$here/SOURCES.md"
