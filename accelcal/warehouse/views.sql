-- accelcal operations views: recalibration history, fleet SQL, rig comparisons.
--
-- Applied idempotently after schema.sql (accelcal.warehouse.views.apply_views); every
-- statement is CREATE OR REPLACE and only reads the append-only history tables
-- of schema.sql, so applying it never changes data.
--
-- Conventions
--   * Values are SI, as stored (effects.md units); display units are the
--     report's business (accelcal.effects.COEFFICIENTS display_factor).
--   * expanded_uncertainty U = k u, k the stored coverage factor (2, or Student's t on the
--     degrees of freedom of a lack-of-fit-scaled u).
--   * calibrated_at = started_at of the earliest input run of the result
--     (from lineage -> run_files), falling back to the result's computed_at.
--   * History, En, the fleet views and the rig comparison read `calibration`:
--     the ADOPTED value of each coefficient (one per result and name, see
--     CoefficientResult.adopted) of the current results that are complete, real
--     (not simulated) and not excluded (campaign_actions).  The other methods'
--     values stay in coefficient_versions / coefficients as cross-checks.
--   * A "coefficient series" is (unit_serial, quantity): the calibrations of one
--     coefficient of one unit, whatever method was adopted (method is a column).
--     quantity is the coefficient a row stands for: its name, or for a combination the
--     design determines (name 'K1(Koq,K3)', accelcal.effects.combination_name) the
--     coefficient kept, 'K1' -- split_part(name, '(', 1); its factors are the JSON
--     column factors ({"K3": 9.55, "Koq": 1.1}: K1 + 9.55 K3 + 1.1 Koq).  A unit
--     recalibrated by tumble alone continues its K1 series.  Where one result adopts the
--     coefficient alone and a combination of it, the series takes the coefficient alone.
--     rig_id is kept alongside (a series may move from one centrifuge to
--     another; rig_comparison is the view for that).
--   * Every *_as_of(ts) macro shows what the warehouse said at time ts:
--     superseded results stay queryable, nothing is overwritten.  ts = NULL
--     means "current" (the plain views are exactly *_as_of(NULL)).

-- When the data behind each result were taken.
CREATE OR REPLACE VIEW result_dates AS
SELECT l.result_id,
       min(TRY_CAST(f.started_at AS TIMESTAMPTZ)) AS first_run_at,
       max(TRY_CAST(f.started_at AS TIMESTAMPTZ)) AS last_run_at,
       count(DISTINCT l.sha256)                   AS n_runs
FROM lineage l
LEFT JOIN (SELECT sha256, any_value(started_at) AS started_at
           FROM run_files GROUP BY sha256) f USING (sha256)
GROUP BY l.result_id;

-- Every coefficient of every result ever stored, current or superseded, with what
-- decides whether it is a calibration: adopted, completeness, simulated, excluded.
CREATE OR REPLACE VIEW coefficient_versions AS
SELECT h.unit_serial, r.unit_model, h.campaign, h.name, split_part(h.name, '(', 1) AS quantity,
       h.factors, h.method, h.rig_id,
       h.value, h.std_uncertainty, h.coverage_factor * h.std_uncertainty AS expanded_uncertainty,
       h.unit, h.dof, h.coverage_factor,
       coalesce(d.first_run_at, r.computed_at) AS calibrated_at, d.last_run_at,
       h.result_id, r.computed_at,
       (h.result_id IN (SELECT result_id FROM results_current)) AS is_current,
       h.seq, h.adopted, r.completeness, r.simulated,
       (h.campaign IN (SELECT campaign FROM excluded_campaigns)) AS excluded
FROM coefficient_history h
JOIN results r USING (result_id)
LEFT JOIN result_dates d USING (result_id);

-- The calibration as of ts (NULL = now): the adopted coefficients of the results
-- current at ts that are complete, real and not excluded at ts.
CREATE OR REPLACE MACRO calibration_as_of(ts) AS TABLE
SELECT unit_serial, unit_model, name, method, rig_id, campaign, calibrated_at,
       value, std_uncertainty, expanded_uncertainty, unit, dof, result_id, computed_at, seq,
       quantity, factors
FROM coefficient_versions
WHERE adopted AND completeness = 'complete' AND NOT simulated
  AND CASE WHEN ts IS NULL THEN is_current
           ELSE result_id IN (SELECT result_id FROM results_as_of(ts)) END
  AND campaign NOT IN (SELECT campaign FROM excluded_campaigns_as_of(ts));

CREATE OR REPLACE VIEW calibration AS
SELECT * EXCLUDE (seq) FROM calibration_as_of(NULL);

-- A unit's history of every coefficient across campaigns, as of ts (NULL = now).
-- calibration_no counts the calibrations of the series, oldest = 1.
CREATE OR REPLACE MACRO unit_history_as_of(ts) AS TABLE
SELECT unit_serial, unit_model, name, method, rig_id, campaign, calibrated_at,
       value, std_uncertainty, expanded_uncertainty, unit, dof, result_id, computed_at,
       row_number() OVER (PARTITION BY unit_serial, quantity
                          ORDER BY calibrated_at, campaign, rig_id, seq) AS calibration_no,
       quantity, factors
FROM (SELECT * FROM calibration_as_of(ts)
      QUALIFY row_number() OVER (PARTITION BY result_id, quantity
                                 ORDER BY factors IS NOT NULL, seq) = 1);

CREATE OR REPLACE VIEW unit_history AS
SELECT * FROM unit_history_as_of(NULL);

-- Change between successive calibrations of a series, with the normalised
-- error En = (x_new - x_prev) / sqrt(U_new^2 + U_prev^2)  (ISO 13528, U = 2u).
-- exceeds_uncertainty: |En| > 1, the change is larger than the combined
-- expanded uncertainty can explain.
CREATE OR REPLACE MACRO coefficient_changes_as_of(ts) AS TABLE
SELECT unit_serial, unit_model, name, method, unit, prev_method,
       prev_campaign, campaign, prev_rig_id, rig_id, (prev_rig_id = rig_id) AS same_rig,
       prev_calibrated_at, calibrated_at,
       prev_value, value, value - prev_value AS change,
       CASE WHEN prev_value <> 0 THEN (value - prev_value) / abs(prev_value) END AS relative_change,
       prev_expanded_uncertainty, expanded_uncertainty,
       sqrt(expanded_uncertainty ^ 2 + prev_expanded_uncertainty ^ 2) AS combined_expanded_uncertainty,
       (value - prev_value)
         / nullif(sqrt(expanded_uncertainty ^ 2 + prev_expanded_uncertainty ^ 2), 0) AS en,
       abs((value - prev_value)
         / nullif(sqrt(expanded_uncertainty ^ 2 + prev_expanded_uncertainty ^ 2), 0)) > 1
         AS exceeds_uncertainty,
       prev_result_id, result_id, calibration_no, quantity, factors, prev_name
FROM (
    SELECT *,
           lag(campaign)             OVER w AS prev_campaign,
           lag(method)               OVER w AS prev_method,
           lag(rig_id)               OVER w AS prev_rig_id,
           lag(calibrated_at)        OVER w AS prev_calibrated_at,
           lag(value)                OVER w AS prev_value,
           lag(expanded_uncertainty) OVER w AS prev_expanded_uncertainty,
           lag(result_id)            OVER w AS prev_result_id,
           lag(name)                 OVER w AS prev_name
    FROM unit_history_as_of(ts)
    WINDOW w AS (PARTITION BY unit_serial, quantity ORDER BY calibration_no)
)
WHERE prev_value IS NOT NULL;

CREATE OR REPLACE VIEW coefficient_changes AS
SELECT * FROM coefficient_changes_as_of(NULL);

-- The latest calibration of every (unit, coefficient, rig): the fleet's state.
CREATE OR REPLACE MACRO fleet_latest_as_of(ts) AS TABLE
SELECT * EXCLUDE (rk) FROM (
    SELECT *, row_number() OVER (PARTITION BY unit_serial, quantity, rig_id
                                 ORDER BY calibration_no DESC) AS rk
    FROM unit_history_as_of(ts)
) WHERE rk = 1;

CREATE OR REPLACE VIEW fleet_latest AS
SELECT * FROM fleet_latest_as_of(NULL);

-- Fleet statistics per unit model, rig and adopted method (latest calibration of
-- each unit).
-- Classical: mean, sample sd, mean +- 3 sd.  Control limits (used for the
-- outlier flag) are robust: median +- 3 * 1.4826 * MAD, because a gross
-- outlier inflates the sd and hides itself (with n units no point can lie
-- further than (n-1)/sqrt(n) sample sds from the mean).  Limits need >= 3 units.
CREATE OR REPLACE MACRO fleet_stats_as_of(ts) AS TABLE
SELECT unit_model, rig_id, name, method, any_value(unit) AS unit,
       count(*) AS n_units,
       avg(value) AS mean, stddev_samp(value) AS sd,
       min(value) AS min, max(value) AS max,
       median(value) AS median, mad(value) AS mad,
       1.482602218505602 * mad(value) AS robust_sd,
       avg(value) - 3 * stddev_samp(value) AS mean_minus_3sd,
       avg(value) + 3 * stddev_samp(value) AS mean_plus_3sd,
       CASE WHEN count(*) >= 3 THEN median(value) - 3 * 1.482602218505602 * mad(value) END AS lcl,
       CASE WHEN count(*) >= 3 THEN median(value) + 3 * 1.482602218505602 * mad(value) END AS ucl,
       avg(expanded_uncertainty) AS mean_expanded_uncertainty,
       min(calibrated_at) AS first_calibrated_at, max(calibrated_at) AS last_calibrated_at
FROM fleet_latest_as_of(ts)
GROUP BY unit_model, rig_id, name, method;

CREATE OR REPLACE VIEW fleet_stats AS
SELECT * FROM fleet_stats_as_of(NULL);

-- Units whose latest value lies outside their model+rig control limits.
CREATE OR REPLACE MACRO fleet_outliers_as_of(ts) AS TABLE
SELECT l.unit_serial, l.unit_model, l.rig_id, l.name, l.method, l.campaign, l.calibrated_at,
       l.value, l.expanded_uncertainty, l.unit, s.median, s.lcl, s.ucl, s.n_units,
       (l.value - s.median) / nullif(s.robust_sd, 0) AS robust_z, l.result_id
FROM fleet_latest_as_of(ts) l
JOIN fleet_stats_as_of(ts) s
  ON s.unit_model IS NOT DISTINCT FROM l.unit_model AND s.rig_id IS NOT DISTINCT FROM l.rig_id
 AND s.name = l.name AND s.method = l.method
WHERE s.lcl IS NOT NULL AND s.robust_sd > 0 AND (l.value < s.lcl OR l.value > s.ucl);

CREATE OR REPLACE VIEW fleet_outliers AS
SELECT * FROM fleet_outliers_as_of(NULL);

-- The same unit's adopted value measured on two or more rigs (e.g. two centrifuges), as in
-- paper 000 Table 5: reference value = arithmetic mean of the rigs' latest
-- values, u_ref = sqrt(sum u_i^2) / n (mean of independent results),
-- En = (x_i - x_ref) / sqrt(U_i^2 + U_ref^2), U = 2u.
CREATE OR REPLACE MACRO rig_comparison_as_of(ts) AS TABLE
WITH per_rig AS (
    SELECT * FROM fleet_latest_as_of(ts)
), ref AS (
    SELECT unit_serial, name, count(*) AS n_rigs,
           avg(value) AS reference_value,
           sqrt(sum(std_uncertainty ^ 2)) / count(*) AS reference_std_uncertainty
    FROM per_rig
    GROUP BY unit_serial, name
    HAVING count(DISTINCT rig_id) >= 2
)
SELECT p.unit_serial, p.unit_model, p.name, p.method, p.rig_id, p.campaign, p.calibrated_at,
       p.value, p.std_uncertainty, p.expanded_uncertainty, p.unit,
       r.n_rigs, r.reference_value, 2.0 * r.reference_std_uncertainty AS reference_expanded_uncertainty,
       p.value - r.reference_value AS deviation,
       (p.value - r.reference_value)
         / nullif(sqrt(p.expanded_uncertainty ^ 2 + (2.0 * r.reference_std_uncertainty) ^ 2), 0) AS en,
       abs((p.value - r.reference_value)
         / nullif(sqrt(p.expanded_uncertainty ^ 2 + (2.0 * r.reference_std_uncertainty) ^ 2), 0)) > 1
         AS exceeds_uncertainty,
       p.result_id
FROM per_rig p JOIN ref r USING (unit_serial, name);

CREATE OR REPLACE VIEW rig_comparison AS
SELECT * FROM rig_comparison_as_of(NULL);

-- Pairwise form for two rigs a < b: En = (x_a - x_b) / sqrt(U_a^2 + U_b^2).
CREATE OR REPLACE VIEW rig_pairs AS
SELECT a.unit_serial, a.unit_model, a.name, a.method AS method_a, b.method AS method_b, a.unit,
       a.rig_id AS rig_a, b.rig_id AS rig_b, a.campaign AS campaign_a, b.campaign AS campaign_b,
       a.value AS value_a, b.value AS value_b,
       a.expanded_uncertainty AS expanded_uncertainty_a,
       b.expanded_uncertainty AS expanded_uncertainty_b,
       a.value - b.value AS difference,
       (a.value - b.value)
         / nullif(sqrt(a.expanded_uncertainty ^ 2 + b.expanded_uncertainty ^ 2), 0) AS en,
       abs((a.value - b.value)
         / nullif(sqrt(a.expanded_uncertainty ^ 2 + b.expanded_uncertainty ^ 2), 0)) > 1
         AS exceeds_uncertainty
FROM fleet_latest a
JOIN fleet_latest b
  ON a.unit_serial = b.unit_serial AND a.name = b.name
 AND a.rig_id < b.rig_id;
