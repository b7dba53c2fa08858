-- accelcal warehouse schema (DuckDB).  Applied idempotently on every open.
--
-- Principles
--   * Nothing is overwritten.  Run records and results are append-only; the
--     "current" tables (coefficients, radii, ...) are VIEWS over the history.
--   * result_id is deterministic: sha256(campaign, sorted input sha256s,
--     code version, parameters).  The same inputs processed twice by the same
--     code are one result.
--   * Which result is current for a campaign is an append-only event
--     (result_activations); the latest activation wins.  As-of queries use the
--     *_as_of(ts) table macros.
--   * Simulated data (files carrying the simulator's mark, accelcal.provenance)
--     are kept apart: a result computed from them is `simulated`, and it is never
--     current for a unit that has a complete real result.
--   * Schema version 2 (schema_info): run_files.simulated, results.simulated /
--     completeness / completeness_reasons, coefficient_history.adopted,
--     campaign_actions.  Schema version 3: results.extras (~48 KB of JSON a result,
--     rewritten whole at every checkpoint) became results.extras_sha256, naming an
--     immutable file in the folder schema_info.extras_dir.  An older warehouse is refused
--     with a one-line message (accelcal.warehouse.db): reprocess its drops into a new
--     warehouse.  Schema version 4: coefficient_history.factors; a row's name is the
--     quantity, never a number from the data (accelcal.effects.combination_name): a
--     combination the design determines is named 'K1(Koq,K3)', its factors in `factors`.

CREATE TABLE IF NOT EXISTS schema_info (
    key   VARCHAR PRIMARY KEY,
    value VARCHAR NOT NULL
);

CREATE SEQUENCE IF NOT EXISTS activation_seq START 1;

-- One row per (file content, file location) seen: the facts of first sight.
-- The same bytes at the same path seen again add nothing.  revision numbers
-- the distinct contents of one run_id in the order they were first ingested.
CREATE TABLE IF NOT EXISTS run_files (
    sha256        VARCHAR   NOT NULL,
    source_path   VARCHAR   NOT NULL,   -- absolute path of the raw file (never modified)
    drop_name     VARCHAR   NOT NULL,
    drop_path     VARCHAR   NOT NULL,
    run_id        VARCHAR,              -- NULL when the file is unreadable
    revision      INTEGER,              -- NULL when run_id is unknown
    test          VARCHAR,
    unit_serial   VARCHAR,
    unit_model    VARCHAR,
    campaign      VARCHAR,
    rig_id        VARCHAR,
    started_at    VARCHAR,
    size_bytes    BIGINT    NOT NULL,
    ingested_at   TIMESTAMPTZ NOT NULL,
    flow_run_id   VARCHAR,
    simulated     BOOLEAN   NOT NULL DEFAULT false,   -- the file carries the simulator's mark
    PRIMARY KEY (sha256, source_path)
);

-- The verdict on a file by one version of the parser + validation suites.
-- Append-only: a new validator version re-checks a file and adds a verdict;
-- the latest verdict is the file's status.
CREATE TABLE IF NOT EXISTS run_verdicts (
    sha256             VARCHAR NOT NULL,
    source_path        VARCHAR NOT NULL,
    validator_version  VARCHAR NOT NULL,
    seq                BIGINT  NOT NULL,   -- order of verdicts
    status             VARCHAR NOT NULL CHECK (status IN ('accepted', 'refused')),
    reason             VARCHAR,            -- NULL when accepted; "path:line: rule: detail; ..."
    n_rows             BIGINT,
    parquet_path       VARCHAR,            -- relative to the warehouse folder; NULL if not parsed
    checked_at         TIMESTAMPTZ NOT NULL,
    flow_run_id        VARCHAR,
    PRIMARY KEY (sha256, source_path, validator_version)
);

CREATE SEQUENCE IF NOT EXISTS verdict_seq START 1;

-- Structured refusals (one file may break several rules).
CREATE TABLE IF NOT EXISTS refusals (
    sha256             VARCHAR NOT NULL,
    source_path        VARCHAR NOT NULL,
    validator_version  VARCHAR NOT NULL,
    seq                INTEGER NOT NULL,
    line               INTEGER,
    rule               VARCHAR NOT NULL,
    detail             VARCHAR,
    PRIMARY KEY (sha256, source_path, validator_version, seq)
);

-- Immutable result records: one per distinct result_id.
CREATE TABLE IF NOT EXISTS results (
    result_id      VARCHAR PRIMARY KEY,
    campaign       VARCHAR NOT NULL,
    unit_serial    VARCHAR NOT NULL,
    unit_model     VARCHAR,
    tests          VARCHAR,         -- JSON list
    rig_ids        VARCHAR,         -- JSON list
    computed_at    TIMESTAMPTZ NOT NULL,
    flow_run_id    VARCHAR,
    code_version   VARCHAR NOT NULL,
    parameters     VARCHAR NOT NULL, -- JSON: pipeline parameters (enter result_id)
    science_parameters VARCHAR,      -- JSON: CampaignResult.parameters
    input_sha256   VARCHAR NOT NULL, -- JSON sorted list
    extras_sha256  VARCHAR,          -- sha256 of CampaignResult.extras as canonical JSON: the
                                     -- file <extras_dir>/<sha[:2]>/<sha>.json (schema_info)
    simulated      BOOLEAN NOT NULL DEFAULT false,  -- computed from simulated runs
    completeness   VARCHAR NOT NULL DEFAULT 'complete'
                   CHECK (completeness IN ('complete', 'incomplete')),
    completeness_reasons VARCHAR     -- JSON list: what the runs could not determine
);

-- Append-only: "result R became the current result of campaign C".
CREATE TABLE IF NOT EXISTS result_activations (
    seq           BIGINT PRIMARY KEY,
    campaign      VARCHAR NOT NULL,
    result_id     VARCHAR NOT NULL,
    activated_at  TIMESTAMPTZ NOT NULL,
    flow_run_id   VARCHAR
);

-- Lineage: every input run of a result, by content hash.
CREATE TABLE IF NOT EXISTS lineage (
    result_id     VARCHAR NOT NULL,
    sha256        VARCHAR NOT NULL,
    run_id        VARCHAR,
    revision      INTEGER,
    source_path   VARCHAR,
    parquet_path  VARCHAR,
    flow_run_id   VARCHAR,
    code_version  VARCHAR NOT NULL,
    parameters    VARCHAR NOT NULL,
    PRIMARY KEY (result_id, sha256)
);

CREATE TABLE IF NOT EXISTS coefficient_history (
    result_id        VARCHAR NOT NULL,
    seq              INTEGER NOT NULL,
    unit_serial      VARCHAR NOT NULL,
    campaign         VARCHAR NOT NULL,
    name             VARCHAR NOT NULL,
    value            DOUBLE,
    std_uncertainty  DOUBLE,
    unit             VARCHAR,
    method           VARCHAR,
    rig_id           VARCHAR,
    dof              DOUBLE,
    note             VARCHAR,
    adopted          BOOLEAN NOT NULL DEFAULT false,  -- the value the lab adopts (one per
                                                      -- result and coefficient name)
    coverage_factor  DOUBLE NOT NULL DEFAULT 2.0,     -- k of U = k u (Student t on few dof)
    factors          VARCHAR,   -- JSON {term: factor}: a combination the design determines
                                -- (name 'K1(Koq,K3)' = K1 + f_K3 K3 + f_Koq Koq); NULL for a
                                -- coefficient determined alone
    PRIMARY KEY (result_id, seq)
);

CREATE TABLE IF NOT EXISTS radius_history (
    result_id          VARCHAR NOT NULL,
    seq                INTEGER NOT NULL,
    campaign           VARCHAR NOT NULL,
    rig_id             VARCHAR,
    polarity           VARCHAR,            -- '+' (phi = 0) or '-' (phi = 180 deg)
    method             VARCHAR,            -- 'static', 'iterative', ... (science's vocabulary)
    model_order        INTEGER,
    g_max              DOUBLE,
    radius_m           DOUBLE,
    std_uncertainty_m  DOUBLE,
    note               VARCHAR,
    PRIMARY KEY (result_id, seq)
);

CREATE TABLE IF NOT EXISTS adequacy_history (
    result_id        VARCHAR NOT NULL,
    seq              INTEGER NOT NULL,
    campaign         VARCHAR NOT NULL,
    rig_id           VARCHAR,
    fit              VARCHAR,
    model_order      INTEGER,
    g_max            DOUBLE,
    f_statistic      DOUBLE,
    p_value          DOUBLE,
    dof_lack_of_fit  INTEGER,
    dof_pure_error   INTEGER,
    trend_p          DOUBLE,
    sweep_p          DOUBLE,
    runs_p           DOUBLE,
    adequate         BOOLEAN,
    chosen           BOOLEAN,
    note             VARCHAR,
    PRIMARY KEY (result_id, seq)
);

CREATE TABLE IF NOT EXISTS budget_history (
    result_id        VARCHAR NOT NULL,
    seq              INTEGER NOT NULL,
    campaign         VARCHAR NOT NULL,
    coefficient      VARCHAR,
    quantity         VARCHAR,
    value            DOUBLE,
    std_uncertainty  DOUBLE,
    sensitivity      DOUBLE,
    contribution     DOUBLE,
    type             VARCHAR,
    distribution     VARCHAR,
    method           VARCHAR,          -- the method of the coefficient it budgets
    PRIMARY KEY (result_id, seq)
);

CREATE TABLE IF NOT EXISTS alignment_history (
    result_id  VARCHAR NOT NULL,
    seq        INTEGER NOT NULL,
    campaign   VARCHAR NOT NULL,
    record     VARCHAR NOT NULL,   -- JSON object
    PRIMARY KEY (result_id, seq)
);

CREATE TABLE IF NOT EXISTS flag_history (
    result_id  VARCHAR NOT NULL,
    seq        INTEGER NOT NULL,
    campaign   VARCHAR NOT NULL,
    flag       VARCHAR NOT NULL,
    PRIMARY KEY (result_id, seq)
);

-- Append-only audit trail of quarantine decisions: a campaign is excluded from
-- history, En, the fleet views and the calibration view from its latest
-- 'exclude' until an 'include' (accelcal campaign exclude|include).
CREATE SEQUENCE IF NOT EXISTS campaign_action_seq START 1;
CREATE TABLE IF NOT EXISTS campaign_actions (
    seq       BIGINT PRIMARY KEY,
    campaign  VARCHAR NOT NULL,
    action    VARCHAR NOT NULL CHECK (action IN ('exclude', 'include')),
    why       VARCHAR NOT NULL CHECK (length(trim(why)) > 0),
    acted_at  TIMESTAMPTZ NOT NULL,
    acted_by  VARCHAR
);

-- ---------------------------------------------------------------- views ----

-- Every file with its latest verdict (the issue's `runs` table).
CREATE OR REPLACE VIEW runs AS
SELECT f.run_id, f.revision, f.sha256, f.source_path, f.test, f.unit_serial, f.campaign,
       v.status, v.reason, f.ingested_at, f.drop_name, f.drop_path, f.unit_model, f.rig_id,
       f.started_at, f.size_bytes, v.n_rows, v.parquet_path, v.validator_version,
       v.checked_at, f.flow_run_id, f.simulated
FROM run_files f
JOIN (SELECT * EXCLUDE (rk) FROM (
        SELECT *, row_number() OVER (PARTITION BY sha256, source_path ORDER BY seq DESC) AS rk
        FROM run_verdicts) WHERE rk = 1) v
  USING (sha256, source_path);

-- The newest revision of every run_id (accepted or not) and whether it is usable.
CREATE OR REPLACE VIEW run_revisions AS
SELECT run_id, revision, sha256,
       any_value(test) AS test, any_value(unit_serial) AS unit_serial,
       any_value(campaign) AS campaign, any_value(rig_id) AS rig_id,
       any_value(status) AS status, any_value(parquet_path) AS parquet_path,
       min(source_path) AS source_path, min(ingested_at) AS ingested_at,
       bool_or(simulated) AS simulated
FROM runs WHERE run_id IS NOT NULL
GROUP BY run_id, revision, sha256;

-- The runs a campaign is computed from: per run_id, its newest accepted revision;
-- a simulated revision never supersedes a real one.
CREATE OR REPLACE VIEW current_runs AS
SELECT * EXCLUDE (rk) FROM (
    SELECT *, row_number() OVER (PARTITION BY run_id ORDER BY simulated, revision DESC) AS rk
    FROM run_revisions WHERE status = 'accepted'
) WHERE rk = 1;

-- Per result, when it was current: [valid_from, valid_to).
CREATE OR REPLACE VIEW result_validity AS
SELECT a.campaign, a.result_id, a.seq, a.activated_at AS valid_from,
       lead(a.activated_at) OVER (PARTITION BY a.campaign ORDER BY a.seq) AS valid_to,
       lead(a.result_id)    OVER (PARTITION BY a.campaign ORDER BY a.seq) AS superseded_by
FROM result_activations a;

-- Units that have a complete real calibration stored (current or not): a simulated
-- result is never current for them.
CREATE OR REPLACE VIEW real_units AS
SELECT DISTINCT unit_serial FROM results WHERE NOT simulated AND completeness = 'complete';

CREATE OR REPLACE VIEW results_current AS
SELECT r.* FROM results r
JOIN result_validity v USING (result_id, campaign)
WHERE v.valid_to IS NULL
  AND NOT (r.simulated AND r.unit_serial IN (SELECT unit_serial FROM real_units));

-- Results with their status (is_current, superseded_by of the latest activation).
-- A result that was never made current (a simulated one for a unit with a real
-- calibration) is listed once, with NULL validity.
CREATE OR REPLACE VIEW result_history AS
SELECT r.*, v.valid_from, v.valid_to, v.superseded_by,
       (r.result_id IN (SELECT result_id FROM results_current)) AS is_current
FROM results r LEFT JOIN result_validity v USING (result_id, campaign);

-- Quarantine as of ts (NULL = now): the campaigns whose latest action is 'exclude'.
CREATE OR REPLACE MACRO excluded_campaigns_as_of(ts) AS TABLE
SELECT campaign, why, acted_at, acted_by FROM (
    SELECT *, row_number() OVER (PARTITION BY campaign ORDER BY seq DESC) AS rk
    FROM campaign_actions WHERE ts IS NULL OR acted_at <= ts
) WHERE rk = 1 AND action = 'exclude';

CREATE OR REPLACE VIEW excluded_campaigns AS
SELECT * FROM excluded_campaigns_as_of(NULL);

CREATE OR REPLACE VIEW coefficients AS
SELECT h.unit_serial, h.campaign, h.name, h.value, h.std_uncertainty,
       h.coverage_factor * h.std_uncertainty AS expanded_uncertainty, h.unit, h.method,
       h.result_id, h.rig_id, h.dof, h.note, h.adopted, h.coverage_factor, c.completeness, c.simulated,
       split_part(h.name, '(', 1) AS quantity, h.factors
FROM coefficient_history h JOIN results_current c USING (result_id)
ORDER BY h.campaign, h.seq;

CREATE OR REPLACE VIEW radii AS
SELECT h.campaign, h.rig_id, h.polarity, h.method, h.model_order, h.g_max,
       h.radius_m, h.std_uncertainty_m, h.result_id, h.note
FROM radius_history h JOIN results_current USING (result_id)
ORDER BY h.campaign, h.seq;

CREATE OR REPLACE VIEW adequacy AS
SELECT h.* EXCLUDE (seq) FROM adequacy_history h JOIN results_current USING (result_id)
ORDER BY h.campaign, h.seq;

CREATE OR REPLACE VIEW uncertainty_budget AS
SELECT h.* EXCLUDE (seq) FROM budget_history h JOIN results_current USING (result_id)
ORDER BY h.campaign, h.seq;

CREATE OR REPLACE VIEW alignment AS
SELECT h.* EXCLUDE (seq) FROM alignment_history h JOIN results_current USING (result_id)
ORDER BY h.campaign, h.seq;

CREATE OR REPLACE VIEW flags AS
SELECT h.* EXCLUDE (seq) FROM flag_history h JOIN results_current USING (result_id)
ORDER BY h.campaign, h.seq;

-- As-of queries: the state the warehouse showed at time ts.
CREATE OR REPLACE MACRO results_as_of(ts) AS TABLE
SELECT r.* FROM results r JOIN result_validity v USING (result_id, campaign)
WHERE v.valid_from <= ts AND (v.valid_to IS NULL OR v.valid_to > ts)
  AND NOT (r.simulated AND r.unit_serial IN (
      SELECT unit_serial FROM results WHERE NOT simulated AND completeness = 'complete'
      AND computed_at <= ts));

CREATE OR REPLACE MACRO coefficients_as_of(ts) AS TABLE
SELECT h.unit_serial, h.campaign, h.name, h.value, h.std_uncertainty,
       h.coverage_factor * h.std_uncertainty AS expanded_uncertainty, h.unit, h.method,
       h.result_id, h.adopted, split_part(h.name, '(', 1) AS quantity, h.factors
FROM coefficient_history h
WHERE h.result_id IN (SELECT result_id FROM results_as_of(ts));

CREATE OR REPLACE MACRO radii_as_of(ts) AS TABLE
SELECT h.campaign, h.rig_id, h.polarity, h.method, h.model_order, h.g_max,
       h.radius_m, h.std_uncertainty_m, h.result_id
FROM radius_history h
WHERE h.result_id IN (SELECT result_id FROM results_as_of(ts));
