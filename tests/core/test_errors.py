def test_a_config_error_survives_pickling_as_benchmark_workers_send_it():
    import pickle

    from stratamap.core.errors import ConfigError

    err = pickle.loads(pickle.dumps(ConfigError([("stages[0].params.x", "extra field")], "p.yaml")))
    assert isinstance(err, ConfigError) and err.problems == [("stages[0].params.x", "extra field")]
    assert str(err) == "p.yaml: stages[0].params.x: extra field"
