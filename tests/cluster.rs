//! A sharded sweep on a real Slurm: scripts/slurm-up.sh brings up a private single-node
//! cluster (munge + slurmctld + slurmd) in a scratch directory, the sweep runs as an array job
//! of deploy/slurm/sweep-array.sbatch and the merge as deploy/slurm/merge.sbatch with
//! `--dependency=afterany`, and the merged summary must equal a local unsharded sweep's.
//!
//! Skipped, with a printed reason, only where the daemons cannot start (not root, Slurm not
//! installed); `MJSAFE_REQUIRE_SLURM=1` (set by scripts/test.sh when it runs as root, after
//! scripts/setup.sh --test installed Slurm) turns that skip into a failure.

mod common;
use common::*;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

const SCENARIO: &str = "scenarios/bicycle_obstacle.toml";
/// 4 runs; run 2 (steering delay −1 s) is rejected, so the shard holding it fails.
const GRID: &str = "delays.steering=0.0,0.1,-1.0,0.2";
const SHARDS: usize = 3;

/// Stops the private Slurm when the test ends, passed or not.
struct Cluster {
    scratch: PathBuf,
    conf: PathBuf,
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new(root().join("scripts/slurm-down.sh"))
            .arg(&self.scratch)
            .status();
    }
}

impl Cluster {
    fn up(scratch: &Path) -> Result<Cluster, String> {
        let o = Command::new(root().join("scripts/slurm-up.sh"))
            .arg(scratch)
            .output()
            .map_err(|e| format!("scripts/slurm-up.sh: {e}"))?;
        // Constructed first so that a failure half-way still stops what started.
        let cluster = Cluster {
            scratch: scratch.to_path_buf(),
            conf: scratch.join("slurm.conf"),
        };
        if o.status.success() {
            println!("{}", stdout(&o).trim());
            Ok(cluster)
        } else {
            Err(text(&o).trim().to_string())
        }
    }

    /// A Slurm client command with this cluster's configuration.
    fn command(&self, program: &str, args: &[&str]) -> Output {
        Command::new(program)
            .args(args)
            .env("SLURM_CONF", &self.conf)
            .output()
            .unwrap_or_else(|e| panic!("{program}: {e}"))
    }

    /// `sbatch --parsable ARGS`: the job id.
    fn sbatch(&self, args: &[&str]) -> String {
        let o = self.command("sbatch", &[&["--parsable"], args].concat());
        assert!(o.status.success(), "sbatch {args:?}: {}", text(&o));
        // `--parsable` prints `id` or `id;cluster`.
        let id = stdout(&o).trim().split(';').next().unwrap().to_string();
        assert!(
            id.chars().all(|c| c.is_ascii_digit()) && !id.is_empty(),
            "job id {id:?}"
        );
        id
    }

    /// Waits until none of `jobs` is pending or running (fails after `limit`, cancelling them).
    fn wait(&self, jobs: &[&str], limit: Duration) {
        let started = Instant::now();
        let list = jobs.join(",");
        loop {
            let o = self.command(
                "squeue",
                &["-h", "-j", &list, "-t", "PENDING,RUNNING,COMPLETING", "-o", "%i %T %r"],
            );
            let queued = stdout(&o);
            if o.status.success() && queued.trim().is_empty() {
                return;
            }
            if started.elapsed() > limit {
                self.command("scancel", jobs);
                panic!(
                    "jobs {list} not done after {limit:?}:\n{queued}\nslurmctld log:\n{}",
                    std::fs::read_to_string(self.scratch.join("log/slurmctld.log")).unwrap_or_default()
                );
            }
            std::thread::sleep(Duration::from_millis(250));
        }
    }

    /// `scontrol -o show job ID`: one map of fields per job record (an array job: one per task).
    fn jobs(&self, id: &str) -> Vec<BTreeMap<String, String>> {
        let o = self.command("scontrol", &["-o", "show", "job", id]);
        assert!(o.status.success(), "scontrol show job {id}: {}", text(&o));
        stdout(&o)
            .lines()
            .filter(|l| !l.trim().is_empty())
            .map(|line| {
                line.split_whitespace()
                    .filter_map(|f| f.split_once('='))
                    .map(|(k, v)| (k.to_string(), v.to_string()))
                    .collect()
            })
            .collect()
    }
}

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn slurm_array_and_afterany_merge_equal_a_local_sweep() {
    let dir = tempfile::tempdir().unwrap();
    let scratch = dir.path().join("slurm");
    let cluster = match Cluster::up(&scratch) {
        Ok(c) => c,
        Err(why) => {
            assert!(
                std::env::var("MJSAFE_REQUIRE_SLURM").as_deref() != Ok("1"),
                "MJSAFE_REQUIRE_SLURM=1 but the Slurm daemons did not start: {why}"
            );
            println!("SKIPPED slurm_array_and_afterany_merge_equal_a_local_sweep: the Slurm daemons cannot start here: {why}");
            return;
        }
    };

    // The reference: the same sweep, unsharded, on this machine. Run 2 fails: exit 3.
    let local = dir.path().join("local");
    let sweep_args = ["--set", "duration=5.0", "--grid", GRID];
    let o = mjsafe(
        &[
            &["sweep", SCENARIO],
            &sweep_args[..],
            &["--out", local.to_str().unwrap()],
        ]
        .concat(),
    );
    assert_eq!(o.status.code(), Some(3), "local sweep: {}", text(&o));

    // The array job (3 shards on 1 CPU each) and its merge, as docs/sweeps.md writes them.
    let out = dir.path().join("cluster-out");
    let out_s = out.to_str().unwrap();
    let bin = env!("CARGO_BIN_EXE_mjsafe");
    let export = format!("--export=ALL,MJSAFE={bin}");
    let chdir = format!("--chdir={}", root().display());
    let array_log = format!("--output={}/sweep-%A_%a.out", scratch.display());
    let array_range = format!("--array=0-{}", SHARDS - 1);
    let script = root().join("deploy/slurm/sweep-array.sbatch");
    let array = cluster.sbatch(
        &[
            &[
                array_range.as_str(),
                "--cpus-per-task=1",
                &export,
                &chdir,
                &array_log,
                script.to_str().unwrap(),
                out_s,
                SCENARIO,
            ][..],
            &sweep_args[..],
        ]
        .concat(),
    );
    let merge_script = root().join("deploy/slurm/merge.sbatch");
    let merge_log = scratch.join("merge.out");
    let merge_log_arg = format!("--output={}", merge_log.display());
    let merge = cluster.sbatch(&[
        &format!("--dependency=afterany:{array}"),
        &export,
        &chdir,
        &merge_log_arg,
        merge_script.to_str().unwrap(),
        out_s,
    ]);
    // What the recipe used to say: afterok never runs once a shard has failed.
    let afterok = cluster.sbatch(&[
        &format!("--dependency=afterok:{array}"),
        &export,
        &chdir,
        "--output=/dev/null",
        "--wrap=true",
    ]);
    let started = Instant::now();
    cluster.wait(&[&array, &merge], Duration::from_secs(300));
    println!(
        "array job {array} ({SHARDS} tasks) and merge job {merge} done in {:.1?}",
        started.elapsed()
    );

    // Each task's exit code: the shard with run 2 exits 3, the others 0.
    let mut codes = BTreeMap::new();
    for task in cluster.jobs(&array) {
        let index: usize = task["ArrayTaskId"].parse().unwrap();
        codes.insert(index, task["ExitCode"].clone());
    }
    let expected: BTreeMap<usize, String> = (0..SHARDS)
        .map(|i| (i, if 2 % SHARDS == i { "3:0" } else { "0:0" }.to_string()))
        .collect();
    assert_eq!(codes, expected, "array task exit codes (ExitCode=status:signal)");
    for i in 0..SHARDS {
        let log = std::fs::read_to_string(scratch.join(format!("sweep-{array}_{i}.out"))).unwrap();
        println!("--- shard {i}:\n{}", log.trim());
        assert!(
            out.join(format!("summary-shard-{i}-of-{SHARDS}.json")).exists(),
            "{log}"
        );
    }

    let merge_job = &cluster.jobs(&merge)[0];
    let merge_text = std::fs::read_to_string(&merge_log).unwrap_or_default();
    println!("--- merge:\n{}", merge_text.trim());
    assert_eq!(merge_job["ExitCode"], "0:0", "merge job: {merge_text}");
    assert!(
        merge_text.contains(&format!("merged {SHARDS} summaries (4 runs)")),
        "{merge_text}"
    );

    let reason = cluster.command("squeue", &["-h", "-j", &afterok, "-o", "%T %r"]);
    assert_eq!(
        stdout(&reason).trim(),
        "PENDING DependencyNeverSatisfied",
        "the afterok job"
    );
    cluster.command("scancel", &[&afterok]);

    for file in ["summary.json", "summary.csv"] {
        assert!(
            read(&out.join(file)) == read(&local.join(file)),
            "the cluster's merged {file} differs from the local sweep's:\n{}\n---\n{}",
            String::from_utf8_lossy(&read(&out.join(file))),
            String::from_utf8_lossy(&read(&local.join(file)))
        );
    }
    let summary: serde_json::Value = serde_json::from_slice(&read(&out.join("summary.json"))).unwrap();
    let runs = summary["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 4);
    assert!(
        runs[2]["error"].as_str().unwrap().contains("delays.steering"),
        "{}",
        runs[2]
    );
    for i in [0, 1, 3] {
        assert_eq!(runs[i]["metrics"]["complete"], true, "{}", runs[i]);
        assert!(out.join(runs[i]["log"].as_str().unwrap()).exists());
    }
    drop(cluster);
    for pid_file in ["slurmctld.pid", "slurmd.pid", "munge/munged.pid"] {
        assert!(
            !scratch.join(pid_file).exists(),
            "{pid_file} left behind: daemon not stopped"
        );
    }
}

/// deploy/kubernetes/sweep-job.yaml, read by PyYAML, agrees with the binary: the exit codes its
/// `podFailurePolicy` acts on are the ones mjsafe uses (3: runs failed → FailIndex, never
/// retried; 1 and 2: broken sweep → FailJob), the shard count is `completions`, `--threads`
/// follows the CPU request, and the command parses as an mjsafe command line.
#[test]
fn kubernetes_job_fails_fast_on_deterministic_exit_codes() {
    use clap::Parser;
    use mjsafe::cli::exit;
    let file = root().join("deploy/kubernetes/sweep-job.yaml");
    let o = Command::new(python())
        .args([
            "-c",
            "import json, sys, yaml; print(json.dumps(yaml.safe_load(open(sys.argv[1]))))",
        ])
        .arg(&file)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "PyYAML (scripts/requirements-test.txt): {}",
        text(&o)
    );
    let job: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let spec = &job["spec"];
    assert_eq!(job["kind"], "Job");
    assert_eq!(spec["completionMode"], "Indexed");
    assert!(
        spec["backoffLimitPerIndex"].as_u64().is_some(),
        "retries counted per index"
    );
    assert_eq!(spec["template"]["spec"]["restartPolicy"], "Never");

    let rules = spec["podFailurePolicy"]["rules"].as_array().unwrap();
    let action_for = |code: u8| -> Option<String> {
        rules
            .iter()
            .find(|r| {
                r["onExitCodes"]["operator"] == "In"
                    && r["onExitCodes"]["values"]
                        .as_array()
                        .is_some_and(|v| v.iter().any(|x| x.as_u64() == Some(u64::from(code))))
            })
            .map(|r| r["action"].as_str().unwrap().to_string())
    };
    assert_eq!(action_for(exit::RUNS_FAILED).as_deref(), Some("FailIndex"));
    assert_eq!(action_for(exit::ERROR).as_deref(), Some("FailJob"));
    assert_eq!(action_for(exit::USAGE).as_deref(), Some("FailJob"));
    // An interruption (eviction's SIGTERM) and a crash are retried.
    assert_eq!(action_for(exit::INTERRUPTED), None);
    assert!(rules
        .iter()
        .any(|r| r["action"] == "Ignore" && r["onPodConditions"][0]["type"] == "DisruptionTarget"));
    let container = &spec["template"]["spec"]["containers"][0];
    for r in rules.iter().filter(|r| r["onExitCodes"].is_object()) {
        assert_eq!(r["onExitCodes"]["containerName"], container["name"]);
    }

    // The command: shards = completions, threads = the CPU request, which equals the limit.
    let script = container["args"][0].as_str().unwrap();
    let completions = spec["completions"].as_u64().unwrap();
    assert!(
        script.contains(&format!("--shard \"${{JOB_COMPLETION_INDEX}}/{completions}\"")),
        "{script}"
    );
    assert_eq!(spec["parallelism"].as_u64(), Some(completions));
    assert!(script.contains("--threads \"${CPUS}\""), "{script}");
    let cpus = container["env"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["name"] == "CPUS")
        .expect("CPUS from the downward API");
    assert_eq!(cpus["valueFrom"]["resourceFieldRef"]["resource"], "requests.cpu");
    assert_eq!(
        container["resources"]["requests"]["cpu"],
        container["resources"]["limits"]["cpu"]
    );
    let argv: Vec<String> = script
        .trim_start_matches("exec ")
        .replace("${JOB_COMPLETION_INDEX}", "0")
        .replace("${CPUS}", "4")
        .split_whitespace()
        .map(|w| w.trim_matches('"').to_string())
        .collect();
    mjsafe::cli::Cli::try_parse_from(&argv).unwrap_or_else(|e| panic!("{argv:?}: {e}"));
    assert!(root().join("scenarios/bicycle_delays.sweep.toml").exists());
}
