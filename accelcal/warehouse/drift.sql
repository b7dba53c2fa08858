-- accelcal drift and due dates: adjustments and the stored forecast.
--
-- Applied by accelcal.ops.due when it first writes (`accelcal campaign adjust`,
-- `accelcal due --store`), inside that write's transaction: a warehouse that never uses
-- them is unchanged.  Every statement is idempotent.  Append-only, like campaign_actions.

-- Audit trail of adjustments: a campaign marked 'adjust' starts a new drift series of its
-- unit (its values are as left after adjusting); 'unadjust' withdraws the mark.
CREATE SEQUENCE IF NOT EXISTS campaign_adjustment_seq START 1;
CREATE TABLE IF NOT EXISTS campaign_adjustments (
    seq       BIGINT PRIMARY KEY,
    campaign  VARCHAR NOT NULL,
    action    VARCHAR NOT NULL CHECK (action IN ('adjust', 'unadjust')),
    why       VARCHAR NOT NULL CHECK (length(trim(why)) > 0),
    acted_at  TIMESTAMPTZ NOT NULL,
    acted_by  VARCHAR
);

CREATE OR REPLACE MACRO adjusted_campaigns_as_of(ts) AS TABLE
SELECT campaign, why, acted_at, acted_by FROM (
    SELECT *, row_number() OVER (PARTITION BY campaign ORDER BY seq DESC) AS rk
    FROM campaign_adjustments WHERE ts IS NULL OR acted_at <= ts
) WHERE rk = 1 AND action = 'adjust';

CREATE OR REPLACE VIEW adjusted_campaigns AS
SELECT * FROM adjusted_campaigns_as_of(NULL);

-- Every forecast `accelcal due --store` computed: one batch per call, one row per unit
-- and coefficient (accelcal.drift.forecast), with what it was computed from.
CREATE SEQUENCE IF NOT EXISTS forecast_batch_seq START 1;
CREATE TABLE IF NOT EXISTS forecast_history (
    batch             BIGINT NOT NULL,
    computed_at       TIMESTAMPTZ NOT NULL,
    as_of             TIMESTAMPTZ,          -- NULL: the warehouse as it was then
    code_version      VARCHAR NOT NULL,
    config_path       VARCHAR,
    config_sha256     VARCHAR,
    risk              DOUBLE NOT NULL,
    unit_serial       VARCHAR NOT NULL,
    unit_model        VARCHAR,
    coefficient       VARCHAR NOT NULL,
    unit              VARCHAR,
    n_campaigns       INTEGER NOT NULL,     -- in the current series
    n_total           INTEGER NOT NULL,     -- every calibration of the coefficient
    last_campaign     VARCHAR,
    last_calibrated   DATE,
    value_in_use      DOUBLE,
    tolerance         DOUBLE,               -- SI; NULL: none in the config
    drift_per_year    DOUBLE,
    u_drift_per_year  DOUBLE,
    due_date          DATE,                 -- NULL: none within 10 years, or no basis
    p_out_at_due      DOUBLE,
    basis             VARCHAR NOT NULL,
    steps             VARCHAR               -- JSON list of flagged steps {campaign, en}
);

-- The latest stored forecast: what `accelcal due --json` printed when it was stored.
CREATE OR REPLACE VIEW recalibration_forecast AS
SELECT unit_serial, unit_model, coefficient, n_campaigns, last_calibrated, drift_per_year,
       u_drift_per_year, due_date, p_out_at_due, basis, unit, n_total, last_campaign,
       value_in_use, tolerance, steps, risk, as_of, computed_at, code_version, config_path,
       config_sha256, batch
FROM forecast_history
WHERE batch = (SELECT max(batch) FROM forecast_history);
