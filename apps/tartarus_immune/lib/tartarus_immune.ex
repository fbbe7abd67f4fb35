defmodule TartarusImmune do
  @moduledoc """
  Immune-inspired selection of the best solution per problem class across a network
  (thesis chapter 6): danger signals, intelligent packets (iPkts) carrying solutions,
  localized idiotypic networks at the nodes, cloning with a population brake,
  hypermutation and apoptosis.

  The pieces:

    * `TartarusImmune.Params` - Table 6.1's constants;
    * `TartarusImmune.Maths` - Eqs. 6.2-6.17, pure, with batch forms;
    * `TartarusImmune.Domain` - the behaviour of a problem domain (features, solutions,
      score, oracle); `TartarusImmune.Sorting` is the first domain;
    * `TartarusImmune.Convergence` - the convergence rule used by every experiment;
    * `TartarusImmune.IPkt` and `TartarusImmune.Node` - the agents;
    * `TartarusImmune.Experiment` - the scenario of §6.5 on `TartarusEmu.Network`;
    * `mix tartarus.select` - the experiments.

  See `docs/immune.md`.
  """
end
