"""The worker loop of vecenv.BatchedSubprocVecEnv. Imports numpy and the env only: no torch."""

import numpy as np


def worker(remote, parent_remote, env_kwargs: dict, n: int) -> None:
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is for the main process (it saves)
    parent_remote.close()
    import env as env_mod

    envs = [env_mod.PandaLeadEnv(**env_kwargs) for _ in range(n)]
    dim = envs[0].observation_space.shape[0]
    obs = np.zeros((n, dim), dtype=np.float32)
    rew = np.zeros(n, dtype=np.float32)
    done = np.zeros(n, dtype=bool)
    try:
        while True:
            cmd, data = remote.recv()
            if cmd == "step":
                infos = []
                for i, e in enumerate(envs):
                    o, r, term, trunc, info = e.step(data[i])
                    d = term or trunc
                    slim = {"TimeLimit.truncated": trunc and not term}
                    if d:
                        slim["terminal_observation"] = o
                        if "failure" in info:
                            slim["failure"] = info["failure"]
                        o, _ = e.reset()
                    obs[i], rew[i], done[i] = o, r, d
                    infos.append(slim)
                remote.send((obs, rew, done, infos))
            elif cmd == "reset":
                seeds, options = data
                for i, e in enumerate(envs):
                    obs[i], _ = e.reset(seed=seeds[i], options=options[i] or None)
                remote.send(obs)
            elif cmd == "get_attr":
                remote.send([getattr(envs[i], data[1]) for i in data[0]])
            elif cmd == "set_attr":
                for i in data[0]:
                    setattr(envs[i], data[1], data[2])
                remote.send(None)
            elif cmd == "env_method":
                idx, name, args, kwargs = data
                remote.send([getattr(envs[i], name)(*args, **kwargs) for i in idx])
            elif cmd == "close":
                for e in envs:
                    e.close()
                remote.close()
                break
            else:
                raise RuntimeError(f"unknown command {cmd!r}")
    except (KeyboardInterrupt, EOFError):
        pass
