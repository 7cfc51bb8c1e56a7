%% @doc The behaviour of a reference VA's mind: the "choose" of the
%% Observe-Choose-Act cycle (paper, Fig. 8). `reference_agents_va' observes
%% (EVATAR's binding reports, the embodiment test, percepts from the sensor
%% emulators, feedback to the actuator emulators' requests, messages from
%% other VAs) and acts; the mind only decides, as a pure function from an
%% observation and its state to a new state and a list of acts.
-module(reference_agents_mind).

-export_type([observation/0, act/0, result/0]).

%% The outcome of a request: `ok' with the feedback's parameters, or what
%% went wrong: EVATAR's Timeout or ProviderGone feedback, an error signal
%% from the device, the emulator not being bound, the connection lost.
-type result() :: {ok, [{binary(), binary()}]} | {failed, binary()}.

-type observation() ::
        {embodied, reference_agents_embodiment:report()}
      | {disembodied, Why :: binary()}
      | {percept, reference_agents_emulator:percept()}
      | {result, Tag :: term(), result()}
      | {progress, Tag :: term(), [{binary(), binary()}]}
      | {message, From :: binary(), Message :: term()}
      | {signal, bil:signal()}.

-type act() ::
        %% A request awaiting feedback from the emulator's bound provider; the
        %% outcome comes back as {result, Tag, Result}.
        {request, Tag :: term(), Emulator :: binary(), Service :: binary(),
         [{binary(), binary()}]}
        %% A request expecting no answer.
      | {send, Emulator :: binary(), Service :: binary(), [{binary(), binary()}]}
        %% A message to another VA, straight between Erlang processes (MAS
        %% communication: not through EVATAR).
      | {tell, To :: binary(), Message :: term()}
        %% A line for the narrator: what was perceived, decided or done.
      | {narrate, perceive | decide | act | info, iodata()}
        %% Something for whoever started the VA: `{reference_agents, Name, Term}'.
      | {notify, term()}.

-callback init(Args :: term()) -> {ok, State :: term()}.

%% How to test one bound relationship of the body (see
%% reference_agents_embodiment:probe()).
-callback probe(reference_agents_emulator:link(), State :: term()) ->
    reference_agents_embodiment:probe().

-callback choose(observation(), Now :: integer(), State :: term()) ->
    {State :: term(), [act()]}.

%% What `reference_agents_va:inspect/1' shows of the mind.
-callback inspect(State :: term()) -> map().
